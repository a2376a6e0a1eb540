// The list of registered models. Adding a model: write its header (see
// brdf/model.h for the members it must and may provide) and add it to this
// list; it is then listed by the CLI, checked by validate/, usable by fit/
// and data_synth/, and covered by every property test. A program can add
// models of its own without editing this list: RegisterModel in
// brdf/model.h, BRDFKIT_REGISTER_MODEL in fit/register_model.h.
#pragma once

#include <tuple>

#include "brdf/lambert.h"
#include "brdf/microfacet.h"
#include "brdf/oren_nayar.h"
#include "brdf/phong.h"
#include "brdf/lafortune.h"
#include "brdf/torrance_sparrow.h"
#include "brdf/ward.h"
#include "brdf/ashikhmin_shirley.h"
#include "brdf/kajiya.h"
#include "brdf/he.h"
#include "brdf/poulin_fournier.h"
#include "brdf/merl.h"
#include "brdf/rgl.h"
#include "brdf/utia.h"
#include "brdf/astm.h"
#include "brdf/rough_dielectric.h"

namespace brdfkit {

using RegisteredModels = std::tuple<
    Lambert,
    OrenNayar,
    OrenNayarFujii,
    PhongOriginal,
    Phong,
    BlinnPhong,
    Lafortune,
    Ggx,
    Beckmann,
    GgxAniso,
    BeckmannAniso,
    GgxSeparable,
    GgxDielectric,
    GgxConductor,
    TorranceSparrow,
    CookTorrance,
    Ward,
    WardDuer,
    WardGmd,
    AshikhminShirley,
    Kajiya,
    He,
    PoulinFournier,
    Merl,
    Rgl,
    Utia,
    Astm,
    GgxGlass,
    GgxGlassCorrelated,
    BeckmannGlass>;

}  // namespace brdfkit
