#include "fit/jet_models.h"

namespace brdfkit::fit {

std::unique_ptr<Bxdf<Jet<4>>> MakeJet4(const Model& model) { return model.Make<Jet<4>>(); }
std::unique_ptr<Bxdf<Jet<8>>> MakeJet8(const Model& model) { return model.Make<Jet<8>>(); }
std::unique_ptr<Bxdf<Jet<16>>> MakeJet16(const Model& model) { return model.Make<Jet<16>>(); }
std::unique_ptr<Bxdf<Jet<32>>> MakeJet32(const Model& model) { return model.Make<Jet<32>>(); }

std::unique_ptr<Bxdf<double>> ModelEvaluators::MakeDouble() const { return model_.Make<double>(); }
std::unique_ptr<Bxdf<Jet<4>>> ModelEvaluators::MakeJet4() const { return fit::MakeJet4(model_); }
std::unique_ptr<Bxdf<Jet<8>>> ModelEvaluators::MakeJet8() const { return fit::MakeJet8(model_); }
std::unique_ptr<Bxdf<Jet<16>>> ModelEvaluators::MakeJet16() const { return fit::MakeJet16(model_); }
std::unique_ptr<Bxdf<Jet<32>>> ModelEvaluators::MakeJet32() const { return fit::MakeJet32(model_); }

}  // namespace brdfkit::fit
