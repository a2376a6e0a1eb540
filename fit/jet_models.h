// Run-time models on ceres::Jet scalars of the sizes the fitter uses. Kept
// in their own translation unit: instantiating every registered model for
// four Jet sizes is the slow part of compiling the fitter.
#pragma once

#include <ceres/jet.h>

#include <memory>

#include "brdf/model.h"

namespace brdfkit::fit {

template <int N>
using Jet = ceres::Jet<double, N>;

std::unique_ptr<Bxdf<Jet<4>>> MakeJet4(const Model& model);
std::unique_ptr<Bxdf<Jet<8>>> MakeJet8(const Model& model);
std::unique_ptr<Bxdf<Jet<16>>> MakeJet16(const Model& model);
std::unique_ptr<Bxdf<Jet<32>>> MakeJet32(const Model& model);

}  // namespace brdfkit::fit
