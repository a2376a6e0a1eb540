// Every registered model on double and float, compiled once for all the
// programs that link brdfkit::validate (brdf/model.h declares them extern).
#include "brdf/model.h"

namespace brdfkit {

template std::unique_ptr<Bxdf<double>> Model::Make<double>() const;
template std::unique_ptr<Bxdf<float>> Model::Make<float>() const;

}  // namespace brdfkit
