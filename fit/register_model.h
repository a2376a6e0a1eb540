// One line that adds a model to the registered models from outside
// brdf/registry.h (a plug-in, or a test-only model):
//
//   BRDFKIT_REGISTER_MODEL(my::Model);
//
// in a source file of the program (not of a static library: its
// initialiser must be linked in). The model is compiled for every scalar
// type the libraries evaluate models on: double, float, and the ceres::Jet
// sizes of the fitter (4, 8, 16, 32), the stress sweep (8) and the property
// tests (1, 2). It is then listed, parsed, checked, tabulated, synthesised,
// fitted and stress-tested like a model of registry.h.
#pragma once

#include "brdf/model.h"
#include "fit/jet_models.h"

#define BRDFKIT_REGISTER_MODEL_CAT2(a, b) a##b
#define BRDFKIT_REGISTER_MODEL_CAT(a, b) BRDFKIT_REGISTER_MODEL_CAT2(a, b)
#define BRDFKIT_REGISTER_MODEL(M)                                                                              \
  namespace {                                                                                                  \
  [[maybe_unused]] const bool BRDFKIT_REGISTER_MODEL_CAT(brdfkit_registered_model_, __LINE__) =                 \
      ::brdfkit::RegisterModel<M, double, float, ::brdfkit::fit::Jet<1>, ::brdfkit::fit::Jet<2>,               \
                               ::brdfkit::fit::Jet<4>, ::brdfkit::fit::Jet<8>, ::brdfkit::fit::Jet<16>,         \
                               ::brdfkit::fit::Jet<32>>();                                                     \
  }                                                                                                            \
  static_assert(true, "")
