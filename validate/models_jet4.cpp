// Every registered model on ceres::Jet<double, 4> (validate/jet_models.h).
#include "validate/jet_models.h"

namespace brdfkit {

template std::unique_ptr<Bxdf<JetN<4>>> Model::Make<JetN<4>>() const;

}  // namespace brdfkit
