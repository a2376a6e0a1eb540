// The list of registered models. Adding a model: write its header (see
// brdf/model.h for the members it provides) and add it to this list; it is
// then listed by the CLI, checked by validate/, usable by fit/ and
// data_synth/, and covered by every property test.
#pragma once

#include <tuple>

#include "brdf/lambert.h"
#include "brdf/merl.h"
#include "brdf/microfacet.h"

namespace brdfkit {

using RegisteredModels = std::tuple<
    Lambert,
    Ggx,
    Beckmann,
    GgxAniso,
    BeckmannAniso,
    GgxSeparable,
    GgxDielectric,
    GgxConductor,
    Merl>;

}  // namespace brdfkit
