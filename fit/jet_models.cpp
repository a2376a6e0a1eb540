#include "fit/jet_models.h"

namespace brdfkit::fit {

std::unique_ptr<Bxdf<double>> ModelEvaluators::MakeDouble() const { return model_.Make<double>(); }
std::unique_ptr<Bxdf<Jet<4>>> ModelEvaluators::MakeJet4() const { return model_.Make<Jet<4>>(); }
std::unique_ptr<Bxdf<Jet<8>>> ModelEvaluators::MakeJet8() const { return model_.Make<Jet<8>>(); }
std::unique_ptr<Bxdf<Jet<16>>> ModelEvaluators::MakeJet16() const { return model_.Make<Jet<16>>(); }
std::unique_ptr<Bxdf<Jet<32>>> ModelEvaluators::MakeJet32() const { return model_.Make<Jet<32>>(); }

}  // namespace brdfkit::fit
