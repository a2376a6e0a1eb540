// Every registered model on ceres::Jet<double, 16> (validate/jet_models.h).
#include "validate/jet_models.h"

namespace brdfkit {

template std::unique_ptr<Bxdf<JetN<16>>> Model::Make<JetN<16>>() const;

}  // namespace brdfkit
