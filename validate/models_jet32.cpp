// Every registered model on ceres::Jet<double, 32> (validate/jet_models.h).
#include "validate/jet_models.h"

namespace brdfkit {

template std::unique_ptr<Bxdf<JetN<32>>> Model::Make<JetN<32>>() const;

}  // namespace brdfkit
