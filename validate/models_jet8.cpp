// Every registered model on ceres::Jet<double, 8> (validate/jet_models.h).
#include "validate/jet_models.h"

namespace brdfkit {

template std::unique_ptr<Bxdf<JetN<8>>> Model::Make<JetN<8>>() const;

}  // namespace brdfkit
