#include "fit/jet_models.h"

namespace brdfkit::fit {

std::unique_ptr<Bxdf<Jet<4>>> MakeJet4(const Model& model) { return model.Make<Jet<4>>(); }
std::unique_ptr<Bxdf<Jet<8>>> MakeJet8(const Model& model) { return model.Make<Jet<8>>(); }
std::unique_ptr<Bxdf<Jet<16>>> MakeJet16(const Model& model) { return model.Make<Jet<16>>(); }
std::unique_ptr<Bxdf<Jet<32>>> MakeJet32(const Model& model) { return model.Make<Jet<32>>(); }

}  // namespace brdfkit::fit
