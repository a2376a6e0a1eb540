// Every registered model on double and float, and the models' constructors
// and tables by name (Model::Parse), compiled once for all the programs that
// link brdfkit::validate (brdf/model.h declares them extern).
#include "brdf/model.h"

namespace brdfkit {

template std::unique_ptr<Bxdf<double>> Model::Make<double>() const;
template std::unique_ptr<Bxdf<float>> Model::Make<float>() const;
namespace detail {
template struct Builtin<RegisteredModels>;
}  // namespace detail

}  // namespace brdfkit
