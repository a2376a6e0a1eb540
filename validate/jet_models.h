// Every registered model on ceres::Jet scalars of the sizes brdfkit
// differentiates with (the fitter's four, the stress sweep's 8), compiled
// once in brdfkit::validate (validate/models_jet*.cpp, one size per unit so
// that they build in parallel) instead of in each translation unit that asks
// for Model::Make on a Jet. ceres/jet.h is header-only: nothing to link.
#pragma once

#include <ceres/jet.h>

#include <memory>

#include "brdf/model.h"

namespace brdfkit {

template <int N>
using JetN = ceres::Jet<double, N>;

#ifdef BRDFKIT_PRECOMPILED_MODELS
extern template std::unique_ptr<Bxdf<JetN<4>>> Model::Make<JetN<4>>() const;
extern template std::unique_ptr<Bxdf<JetN<8>>> Model::Make<JetN<8>>() const;
extern template std::unique_ptr<Bxdf<JetN<16>>> Model::Make<JetN<16>>() const;
extern template std::unique_ptr<Bxdf<JetN<32>>> Model::Make<JetN<32>>() const;
#endif

}  // namespace brdfkit
