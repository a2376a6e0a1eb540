// Run-time models on ceres::Jet scalars of the sizes the fitter uses
// (compiled once in brdfkit::validate, see validate/jet_models.h).
#pragma once

#include <memory>

#include "brdf/model.h"
#include "validate/jet_models.h"

namespace brdfkit::fit {

template <int N>
using Jet = JetN<N>;

// What the fitter needs of a model: its parameter table and its evaluators
// on double and on the Jet sizes it differentiates with. ModelEvaluators
// serves a registered model; a model outside the registry (a Python
// function) implements its own.
class Evaluators {
 public:
  virtual ~Evaluators() = default;
  virtual const ModelInfo& Info() const = 0;
  virtual std::unique_ptr<Bxdf<double>> MakeDouble() const = 0;
  virtual std::unique_ptr<Bxdf<Jet<4>>> MakeJet4() const = 0;
  virtual std::unique_ptr<Bxdf<Jet<8>>> MakeJet8() const = 0;
  virtual std::unique_ptr<Bxdf<Jet<16>>> MakeJet16() const = 0;
  virtual std::unique_ptr<Bxdf<Jet<32>>> MakeJet32() const = 0;
  // The registered model behind these evaluators, if any: the start search
  // switches its lobes off and on (a model outside the registry has none).
  virtual const Model* AsModel() const { return nullptr; }
};

class ModelEvaluators final : public Evaluators {
 public:
  explicit ModelEvaluators(const Model& model) : model_(model) {}
  const ModelInfo& Info() const override { return model_.Info(); }
  std::unique_ptr<Bxdf<double>> MakeDouble() const override;
  std::unique_ptr<Bxdf<Jet<4>>> MakeJet4() const override;
  std::unique_ptr<Bxdf<Jet<8>>> MakeJet8() const override;
  std::unique_ptr<Bxdf<Jet<16>>> MakeJet16() const override;
  std::unique_ptr<Bxdf<Jet<32>>> MakeJet32() const override;
  const Model* AsModel() const override { return &model_; }

 private:
  const Model& model_;
};

}  // namespace brdfkit::fit
