// Run-time models: a parsed model specification ("ggx", "lambert+ggx",
// "merl:file.binary"), its expanded parameter table, and Bxdf<T> evaluators
// for any scalar type T (double, float, ceres::Jet).
//
// A model class M (one lobe) provides
//   static ModelInfo Info();
//   explicit M(const Settings&);
//   template <class T> Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const;
//     (or template <class T, class V = T> with Vec3<V> directions: Bxdf::EvalAt
//     then keeps double directions in double on Jet parameters, as a fit's Jacobian wants)
// and optionally
//   template <class T> BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const;
//   template <class T> T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const;
//     (both or neither; without them the sampling checks are skipped)
//   static constexpr unsigned kKind;   // LobeKind flags: diffuse, glossy, specular, transmission
// and optionally
//   static constexpr std::array<Slot, N> kSlots;  // its parameters by name (see Slot)
//   LobeWidth Width(const double* p) const;       // required when kKind has kGlossy
//   static constexpr bool kChannelsIndependent;   // channel c reads only channel c (default false)
//   static constexpr bool kVanishes;  // zero everywhere once its colour parameters whose range
//                                     // starts at 0 are 0 (default false: a sum gives it a weight)
//   double SampleWeight(const double* p) const;                  // lobe choice in sums
//   template <class T> T D(const T* p, const Vec3<T>& wm) const;  // microfacet models
//   template <class T> T G1(const T* p, const Vec3<T>& w, const Vec3<T>& wm) const;  // Smith
//   template <class T> T RelativeIndex(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const;
//     (eta_wi / eta_wo; required when kKind has kTransmission, see Bxdf::RelativeIndex)
//   template <class T> void EvalBatch(const T* p, const T* wi, std::size_t wi_stride, const T* wo,
//                                     std::size_t wo_stride, std::size_t n, T* out) const;
//     Eval over n pairs (the layout of brdf/batch.h), typically a vectorised
//     kernel run by RunBatchKernel; for the scalar types it accepts (the
//     others, ceres::Jet among them, take the generic loop of brdf/batch.h)
// and is listed once in registry.h. The traits are read in one place,
// detail::Traits below, and reach the tools through Bxdf::Kind, Width and
// ChannelsIndependent.
#pragma once

#include "brdf/batch.h"
#include "brdf/core.h"
#include "brdf/registry.h"

#include <algorithm>
#include <array>
#include <concepts>
#include <sstream>
#include <string_view>
#include <typeindex>
#include <typeinfo>
#include <utility>

namespace brdfkit {

// What a registered model declares about itself, without building it (a
// model with settings may need a file): its kind, whether its channels are
// independent, and the named slots it reads its parameters through (empty
// for a model without parameters). All zero for an unknown name.
struct DeclaredTraits {
  unsigned kind = 0;
  bool channels_independent = false;
  std::vector<Slot> slots;
  bool vanishes = false;
};

namespace detail {

// The one reader of a model's declared traits.
template <typename M>
struct Traits {
  static_assert(requires { M::kKind; }, "a model declares its kind: static constexpr unsigned kKind = LobeKind::...");
  static constexpr unsigned kKind = M::kKind;
  static constexpr bool kHasWidth = requires(const M& m, const double* p) {
    { m.Width(p) } -> std::same_as<LobeWidth>;
  };
  static_assert(kHasWidth || !(kKind & LobeKind::kGlossy),
                "a glossy model declares its lobe width: LobeWidth Width(const double* p) const");
  static constexpr bool kHasRelativeIndex = requires(const M& m, const double* p, const Vec3<double>& w) {
    { m.template RelativeIndex<double>(p, w, w) } -> std::same_as<double>;
  };
  static_assert(kHasRelativeIndex || !(kKind & LobeKind::kTransmission),
                "a transmitting model declares its index ratio: T RelativeIndex(const T* p, wi, wo) const");
  static constexpr bool kChannelsIndependent = [] {
    if constexpr (requires { M::kChannelsIndependent; }) return bool(M::kChannelsIndependent);
    return false;
  }();
  static constexpr bool kVanishes = [] {
    if constexpr (requires { M::kVanishes; }) return bool(M::kVanishes);
    return false;
  }();
  static std::vector<Slot> Slots() {
    if constexpr (requires { M::kSlots; }) return std::vector<Slot>(M::kSlots.begin(), M::kSlots.end());
    return {};
  }
  static LobeWidth Width(const M& m, const double* p) {
    if constexpr (kHasWidth) return m.Width(p);
    return {};
  }
};

template <typename M, typename T>
class MicrofacetAdapter final : public MicrofacetView<T> {
 public:
  explicit MicrofacetAdapter(const M* m) : m_(m) {}
  T D(const T* p, const Vec3<T>& wm) const override { return m_->template D<T>(p, wm); }
  bool HasSmithG1() const override {
    return requires(const M& m, const T* p, const Vec3<T>& w) { m.template G1<T>(p, w, w); };
  }
  T G1(const T* p, const Vec3<T>& w, const Vec3<T>& wm) const override {
    if constexpr (requires(const M& m) { m.template G1<T>(p, w, wm); }) {
      return m_->template G1<T>(p, w, wm);
    } else {
      throw ModelError(M::Info().name + " has no Smith masking function");
    }
  }

 private:
  const M* m_;
};

template <typename M, typename T>
class ModelAdapter final : public Bxdf<T> {
 public:
  ModelAdapter(std::shared_ptr<const M> m, ModelInfo info) : m_(std::move(m)), info_(std::move(info)) {
    if constexpr (requires(const M& mm, const T* p, const Vec3<T>& w) { mm.template D<T>(p, w); })
      micro_ = std::make_unique<MicrofacetAdapter<M, T>>(m_.get());
  }
  const ModelInfo& Info() const override { return info_; }
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const override {
    return m_->template Eval<T>(p, wi, wo);
  }
  Rgb<T> EvalAt(const T* p, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const override {
    // Eval<T, double> names the directions' type: Eigen's converting
    // constructor would let Eval<T> accept double directions and then fail to compile.
    if constexpr (requires(const M& mm, const Vec3<double>& w) { mm.template Eval<T, double>(p, w, w); })
      return m_->template Eval<T, double>(p, Vec3<double>(wi), Vec3<double>(wo));
    else
      return Bxdf<T>::EvalAt(p, wi, wo);
  }
  Rgb<T> EvalSum(const T* p, const Vec3<T>& wi, const Vec3<T>* wo, const double* w, std::size_t n) const override {
    Rgb<T> sum = Rgb<T>::Constant(T(0));
    for (std::size_t k = 0; k < n; ++k) sum += m_->template Eval<T>(p, wi, wo[k]) * T(w[k]);
    return sum;
  }
  static constexpr bool kSamples = requires(const M& mm, const T* p, const Vec3<T>& w) {
    mm.template Sample<T>(p, w, 0.5, 0.5);
    mm.template Pdf<T>(p, w, w);
  };
  void EvalBatch(const T* p, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride, std::size_t n,
                 T* out) const override {
    if constexpr (requires(const M& mm) { mm.template EvalBatch<T>(p, wi, wi_stride, wo, wo_stride, n, out); })
      m_->template EvalBatch<T>(p, wi, wi_stride, wo, wo_stride, n, out);
    else
      brdfkit::EvalBatch(*m_, p, wi, wi_stride, wo, wo_stride, n, out);
  }
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const override {
    if constexpr (kSamples) return m_->template Sample<T>(p, wo, u1, u2);
    else return BsdfSample<T>{};
  }
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const override {
    if constexpr (kSamples) return m_->template Pdf<T>(p, wo, wi);
    else return T(0);
  }
  bool CanSample() const override { return kSamples; }
  double SampleWeight(const double* p) const override {
    if constexpr (requires(const M& mm) { mm.SampleWeight(p); }) {
      return m_->SampleWeight(p);
    } else {
      return 1.0;
    }
  }
  const MicrofacetView<T>* Microfacet() const override { return micro_.get(); }
  T RelativeIndex(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const override {
    if constexpr (Traits<M>::kHasRelativeIndex) return m_->template RelativeIndex<T>(p, wi, wo);
    else return T(1);
  }
  unsigned Kind() const override { return Traits<M>::kKind; }
  LobeWidth Width(const double* p) const override { return Traits<M>::Width(*m_, p); }
  bool ChannelsIndependent() const override { return Traits<M>::kChannelsIndependent; }

 private:
  std::shared_ptr<const M> m_;
  ModelInfo info_;
  std::unique_ptr<MicrofacetView<T>> micro_;
};

// Sum of lobes: f = sum_k w_k f_k, w_k the lobe's `weight` parameter where
// it has one (Model::Parse) and 1 otherwise; sampling picks lobe k with
// probability proportional to w_k times its SampleWeight and the pdf is the
// mixture density.
template <typename T>
class SumBxdf final : public Bxdf<T> {
 public:
  // weights[k]: packed index of lobe k's weight, or -1 when it has none.
  SumBxdf(std::vector<std::unique_ptr<Bxdf<T>>> lobes, std::vector<std::size_t> offsets,
          std::vector<std::ptrdiff_t> weights, ModelInfo info)
      : lobes_(std::move(lobes)), offsets_(std::move(offsets)), weights_(std::move(weights)), info_(std::move(info)) {}
  const ModelInfo& Info() const override { return info_; }
  Rgb<T> Eval(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const override {
    Rgb<T> f = Rgb<T>::Constant(T(0));
    for (std::size_t k = 0; k < lobes_.size(); ++k) {
      if (weights_[k] < 0) f += lobes_[k]->Eval(p + offsets_[k], wi, wo);
      else f += lobes_[k]->Eval(p + offsets_[k], wi, wo) * p[weights_[k]];
    }
    return f;
  }
  Rgb<T> EvalAt(const T* p, const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) const override {
    Rgb<T> f = Rgb<T>::Constant(T(0));
    for (std::size_t k = 0; k < lobes_.size(); ++k) {
      if (weights_[k] < 0) f += lobes_[k]->EvalAt(p + offsets_[k], wi, wo);
      else f += lobes_[k]->EvalAt(p + offsets_[k], wi, wo) * p[weights_[k]];
    }
    return f;
  }
  Rgb<T> EvalSum(const T* p, const Vec3<T>& wi, const Vec3<T>* wo, const double* w, std::size_t n) const override {
    Rgb<T> f = Rgb<T>::Constant(T(0));
    for (std::size_t k = 0; k < lobes_.size(); ++k) {
      if (weights_[k] < 0) f += lobes_[k]->EvalSum(p + offsets_[k], wi, wo, w, n);
      else f += lobes_[k]->EvalSum(p + offsets_[k], wi, wo, w, n) * p[weights_[k]];
    }
    return f;
  }
  // Lobe by lobe over chunks small enough to stay in cache.
  void EvalBatch(const T* p, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride, std::size_t n,
                 T* out) const override {
    constexpr std::size_t kChunk = 256;
    T part[3 * kChunk];
    for (std::size_t start = 0; start < n; start += kChunk) {
      const std::size_t m = std::min(kChunk, n - start);
      const T* a = wi + start * wi_stride;
      const T* b = wo + start * wo_stride;
      T* o = out + 3 * start;
      lobes_[0]->EvalBatch(p + offsets_[0], a, wi_stride, b, wo_stride, m, o);
      if (weights_[0] >= 0)
        for (std::size_t i = 0; i < 3 * m; ++i) o[i] *= p[weights_[0]];
      for (std::size_t k = 1; k < lobes_.size(); ++k) {
        lobes_[k]->EvalBatch(p + offsets_[k], a, wi_stride, b, wo_stride, m, part);
        if (weights_[k] < 0)
          for (std::size_t i = 0; i < 3 * m; ++i) o[i] += part[i];
        else
          for (std::size_t i = 0; i < 3 * m; ++i) o[i] += part[i] * p[weights_[k]];
      }
    }
  }
  BsdfSample<T> Sample(const T* p, const Vec3<T>& wo, double u1, double u2) const override {
    const std::vector<double> w = Weights(p);
    std::size_t k = 0;
    double acc = 0;
    for (; k + 1 < lobes_.size(); ++k) {
      if (u1 < acc + w[k]) break;
      acc += w[k];
    }
    // Reuse u1 inside the chosen lobe's interval; the clamp keeps it below 1
    // when rounding puts it on the interval's end.
    const double u1k = std::min((u1 - acc) / w[k], 1.0 - 1e-16);
    BsdfSample<T> s = lobes_[k]->Sample(p + offsets_[k], wo, u1k, u2);
    if (!s.valid) return s;
    s.pdf = Pdf(p, wo, s.wi);
    return s;
  }
  T Pdf(const T* p, const Vec3<T>& wo, const Vec3<T>& wi) const override {
    const std::vector<double> w = Weights(p);
    T pdf = T(0);
    for (std::size_t k = 0; k < lobes_.size(); ++k)
      if (w[k] > 0) pdf += T(w[k]) * lobes_[k]->Pdf(p + offsets_[k], wo, wi);
    return pdf;
  }
  double SampleWeight(const double* p) const override {
    double s = 0;
    for (std::size_t k = 0; k < lobes_.size(); ++k) s += LobeWeight(p, k) * lobes_[k]->SampleWeight(p + offsets_[k]);
    return s;
  }
  bool CanSample() const override {
    return std::all_of(lobes_.begin(), lobes_.end(), [](const auto& l) { return l->CanSample(); });
  }
  unsigned Kind() const override {
    unsigned k = 0;
    for (const auto& l : lobes_) k |= l->Kind();
    return k;
  }
  // That of the first transmitting lobe: the others scatter only within a
  // side, where the ratio is 1 (a sum of interfaces of different index has
  // no generalised reciprocity to check).
  T RelativeIndex(const T* p, const Vec3<T>& wi, const Vec3<T>& wo) const override {
    for (std::size_t k = 0; k < lobes_.size(); ++k)
      if (lobes_[k]->Kind() & LobeKind::kTransmission) return lobes_[k]->RelativeIndex(p + offsets_[k], wi, wo);
    return T(1);
  }
  // The narrowest lobe of the sum along each axis.
  LobeWidth Width(const double* p) const override {
    LobeWidth w;
    const auto take = [](double& cur, double v) { cur = cur > 0 ? std::min(cur, v) : v; };
    for (std::size_t k = 0; k < lobes_.size(); ++k) {
      const LobeWidth l = lobes_[k]->Width(p + offsets_[k]);
      if (!l.Any()) continue;
      take(w.x, l.x);
      take(w.y, l.y);
    }
    return w;
  }
  bool ChannelsIndependent() const override {
    for (const auto& l : lobes_)
      if (!l->ChannelsIndependent()) return false;
    return true;
  }

 private:
  std::vector<double> Weights(const T* p) const {
    const std::size_t n = info_.PackedSize();
    std::vector<double> pv(n);
    for (std::size_t i = 0; i < n; ++i) pv[i] = Value(p[i]);
    std::vector<double> w(lobes_.size());
    double total = 0;
    for (std::size_t k = 0; k < lobes_.size(); ++k) {
      w[k] = std::max(0.0, LobeWeight(pv.data(), k) * lobes_[k]->SampleWeight(pv.data() + offsets_[k]));
      total += w[k];
    }
    // All lobes black: sample them evenly so the pdf stays a density.
    if (!(total > 0)) {
      std::fill(w.begin(), w.end(), 1.0 / lobes_.size());
      return w;
    }
    for (double& x : w) x /= total;
    return w;
  }

  double LobeWeight(const double* p, std::size_t k) const { return weights_[k] < 0 ? 1.0 : p[weights_[k]]; }

  std::vector<std::unique_ptr<Bxdf<T>>> lobes_;
  std::vector<std::size_t> offsets_;
  std::vector<std::ptrdiff_t> weights_;
  ModelInfo info_;
};

// f(index, (M*)nullptr) for each model M of the tuple Models in turn, until f returns true.
template <typename Models = RegisteredModels, std::size_t I = 0, typename F>
bool ForEachModelType(F&& f) {
  if constexpr (I < std::tuple_size_v<Models>) {
    using M = std::tuple_element_t<I, Models>;
    if (f(I, static_cast<M*>(nullptr))) return true;
    return ForEachModelType<Models, I + 1>(std::forward<F>(f));
  }
  return false;
}

template <typename T>
using MakeFn = std::unique_ptr<Bxdf<T>> (*)(const std::shared_ptr<const void>&, const ModelInfo&);

template <typename M, typename T>
std::unique_ptr<Bxdf<T>> MakeAdapter(const std::shared_ptr<const void>& impl, const ModelInfo& info) {
  return std::make_unique<ModelAdapter<M, T>>(std::static_pointer_cast<const M>(impl), info);
}

// A model added at run time by RegisterModel: its table, its constructor and
// its adapters for the scalar types it was registered with (MakeFn<T> by
// typeid(T), stored as a plain function pointer).
struct ExtensionModel {
  ModelInfo info;
  DeclaredTraits traits;
  std::shared_ptr<const void> (*construct)(const Settings&) = nullptr;
  std::map<std::type_index, void (*)()> make;
};

inline std::vector<ExtensionModel>& ExtensionModels() {
  static std::vector<ExtensionModel> models;
  return models;
}

// A model made from its name and settings: a lobe of a Model.
struct MadeModel {
  std::size_t index = 0;  // in RegisteredModels, then in ExtensionModels() after them
  bool vanishes = false;  // zero everywhere with its colour parameters at 0 (Traits::kVanishes)
  ModelInfo info;
  std::shared_ptr<const void> impl;
};

// Settings s for the model `name` of table info, with arg (when not empty)
// as the value of its first setting. Throws ModelError on an argument or a
// setting the model does not take.
inline void TakeSettings(const std::string& name, const ModelInfo& info, const std::string& arg, Settings& s) {
  if (!arg.empty()) {
    if (info.settings.empty()) throw ModelError("model '" + name + "' takes no ':' argument (got '" + arg + "')");
    s[info.settings.front()] = arg;
  }
  for (const auto& [k, v] : s)
    if (std::find(info.settings.begin(), info.settings.end(), k) == info.settings.end())
      throw ModelError("model '" + name + "' has no setting '" + k + "'");
}

// The models of the tuple Models (registry.h's) by name: their tables,
// traits and constructors; indices are positions in Models. Every
// registered model's constructor and table are instantiated here, so
// programs that link brdfkit::validate get them compiled once, in
// validate/models.cpp (extern below), instead of in each translation unit
// that parses a model. Members defined outside the class: not inline, so
// that the extern declaration holds.
template <typename Models = RegisteredModels>
struct Builtin {
  static std::vector<ModelInfo> Infos();
  // false when no model of registry.h is called `name`.
  static bool TraitsOf(const std::string& name, DeclaredTraits& out);
  // The model `name` with settings s, arg (when not empty) the value of its
  // first setting; false when no model of registry.h is called `name`.
  // Throws ModelError on an argument or setting the model does not take.
  static bool Make(const std::string& name, const std::string& arg, Settings s, MadeModel& out);
};

template <typename Models>
std::vector<ModelInfo> Builtin<Models>::Infos() {
  std::vector<ModelInfo> out;
  ForEachModelType<Models>([&](std::size_t, auto* tag) {
    out.push_back(std::remove_pointer_t<decltype(tag)>::Info());
    return false;
  });
  return out;
}

template <typename Models>
bool Builtin<Models>::TraitsOf(const std::string& name, DeclaredTraits& out) {
  return ForEachModelType<Models>([&](std::size_t, auto* tag) {
    using M = std::remove_pointer_t<decltype(tag)>;
    if (M::Info().name != name) return false;
    out = {Traits<M>::kKind, Traits<M>::kChannelsIndependent, Traits<M>::Slots(), Traits<M>::kVanishes};
    return true;
  });
}

template <typename Models>
bool Builtin<Models>::Make(const std::string& name, const std::string& arg, Settings s, MadeModel& out) {
  return ForEachModelType<Models>([&](std::size_t index, auto* tag) {
    using M = std::remove_pointer_t<decltype(tag)>;
    ModelInfo info = M::Info();
    if (info.name != name) return false;
    TakeSettings(name, info, arg, s);
    out.index = index;
    out.vanishes = Traits<M>::kVanishes;
    out.info = std::move(info);
    out.impl = std::make_shared<const M>(s);
    return true;
  });
}

#ifdef BRDFKIT_PRECOMPILED_MODELS
extern template struct Builtin<RegisteredModels>;
#endif

}  // namespace detail

// Static description of every registered model: the list in registry.h,
// then those added by RegisterModel, in registration order.
inline std::vector<ModelInfo> RegisteredModelInfos() {
  std::vector<ModelInfo> out = detail::Builtin<>::Infos();
  for (const detail::ExtensionModel& e : detail::ExtensionModels()) out.push_back(e.info);
  return out;
}

// The declared traits of the registered model `model_name`.
inline DeclaredTraits TraitsOf(const std::string& model_name) {
  DeclaredTraits out;
  detail::Builtin<>::TraitsOf(model_name, out);
  for (const detail::ExtensionModel& e : detail::ExtensionModels())
    if (e.info.name == model_name) out = e.traits;
  return out;
}

// Adds model M (the members of a registry.h model) to the registered models
// from outside brdf/registry.h, compiled for the scalar types Scalars...
// (typically double, float and the ceres::Jet sizes the tools use; see
// BRDFKIT_REGISTER_MODEL in fit/register_model.h). Called before main, from
// a static initialiser of the program that links it in. Throws ModelError
// when the name is taken.
template <typename M, typename... Scalars>
bool RegisterModel() {
  detail::ExtensionModel e;
  e.info = M::Info();
  for (const ModelInfo& i : RegisteredModelInfos())
    if (i.name == e.info.name) throw ModelError("model '" + e.info.name + "' is registered twice");
  e.traits = {detail::Traits<M>::kKind, detail::Traits<M>::kChannelsIndependent, detail::Traits<M>::Slots(),
              detail::Traits<M>::kVanishes};
  e.construct = [](const Settings& s) -> std::shared_ptr<const void> { return std::make_shared<const M>(s); };
  (e.make.emplace(std::type_index(typeid(Scalars)),
                  reinterpret_cast<void (*)()>(static_cast<detail::MakeFn<Scalars>>(&detail::MakeAdapter<M, Scalars>))),
   ...);
  detail::ExtensionModels().push_back(std::move(e));
  return true;
}

// A parsed model specification. Copies share the loaded model data.
class Model {
 public:
  // spec: "name", "name:setting" (the model's first setting, e.g. a path),
  // or a sum "a+b+c" of those. settings apply to a single-lobe model.
  static Model Parse(const std::string& spec, const Settings& settings = {}) {
    Model m;
    m.spec_ = spec;
    std::vector<std::string> parts;
    {
      std::string cur;
      for (char c : spec) {
        if (c == '+') {
          parts.push_back(cur);
          cur.clear();
        } else {
          cur.push_back(c);
        }
      }
      parts.push_back(cur);
    }
    if (spec.empty()) throw ModelError("empty model name (expected one of: " + KnownNames() + ")");
    std::map<std::string, int> seen;
    for (const std::string& part : parts) {
      Lobe lobe;
      std::string name = part, arg;
      const auto colon = part.find(':');
      if (colon != std::string::npos) {
        name = part.substr(0, colon);
        arg = part.substr(colon + 1);
      }
      if (name.empty())
        throw ModelError("model '" + spec + "': empty lobe name in a sum (expected e.g. lambert+ggx)");
      Settings s = parts.size() == 1 ? settings : Settings{};
      bool found = detail::Builtin<>::Make(name, arg, s, lobe);
      for (std::size_t k = 0; !found && k < detail::ExtensionModels().size(); ++k) {
        const detail::ExtensionModel& e = detail::ExtensionModels()[k];
        if (e.info.name != name) continue;
        detail::TakeSettings(name, e.info, arg, s);
        lobe.index = std::tuple_size_v<RegisteredModels> + k;
        lobe.vanishes = e.traits.vanishes;
        lobe.info = e.info;
        lobe.impl = e.construct(s);
        found = true;
      }
      if (!found)
        throw ModelError("unknown model '" + name + "'" + (parts.size() > 1 ? " in '" + spec + "'" : "") +
                         " (known models: " + KnownNames() + ")" + DidYouMean(name, KnownModelNames()));
      const int count = ++seen[name];
      lobe.prefix = count == 1 ? name : name + "#" + std::to_string(count);
      m.lobes_.push_back(std::move(lobe));
    }
    m.BuildInfo();
    return m;
  }

  const ModelInfo& Info() const { return info_; }
  const std::string& Spec() const { return spec_; }
  std::size_t LobeCount() const { return lobes_.size(); }
  const ModelInfo& LobeInfo(std::size_t k) const { return lobes_[k].info; }
  std::size_t LobeOffset(std::size_t k) const { return offsets_[k]; }
  // Packed index of lobe k's weight in a sum, or -1 when it has none.
  std::ptrdiff_t LobeWeightIndex(std::size_t k) const { return weights_[k]; }
  // "ggx", "ggx#2": the prefix of lobe k's parameter names in a sum.
  const std::string& LobePrefix(std::size_t k) const { return lobes_[k].prefix; }
  // Lobe k alone: a one-lobe model with the parameters of LobeInfo(k) (no
  // weight), sharing the loaded data.
  Model LobeAlone(std::size_t k) const {
    Model m;
    m.spec_ = lobes_[k].info.name;
    m.lobes_ = {lobes_[k]};
    m.BuildInfo();
    return m;
  }

  // The run-time model on scalar T (every registered model is compiled for T).
  template <typename T>
  std::unique_ptr<Bxdf<T>> Make() const;

  static std::vector<KnownName> KnownModelNames() {
    std::vector<KnownName> out;
    for (const ModelInfo& i : RegisteredModelInfos()) out.push_back({i.name, ""});
    return out;
  }

  static std::string KnownNames() {
    std::string s;
    for (const ModelInfo& i : RegisteredModelInfos()) s += (s.empty() ? "" : ", ") + i.name;
    return s;
  }

 private:
  struct Lobe : detail::MadeModel {
    std::string prefix;
  };

  template <typename T>
  static std::unique_ptr<Bxdf<T>> MakeLobe(const Lobe& l, const ModelInfo& info) {
    std::unique_ptr<Bxdf<T>> out;
    detail::ForEachModelType([&](std::size_t index, auto* tag) {
      using M = std::remove_pointer_t<decltype(tag)>;
      if (index != l.index) return false;
      out = detail::MakeAdapter<M, T>(l.impl, info);
      return true;
    });
    if (out) return out;
    const detail::ExtensionModel& e = detail::ExtensionModels().at(l.index - std::tuple_size_v<RegisteredModels>);
    const auto make = e.make.find(std::type_index(typeid(T)));
    if (make == e.make.end())
      throw ModelError("model '" + e.info.name + "' was not registered for the scalar type " + typeid(T).name());
    return reinterpret_cast<detail::MakeFn<T>>(make->second)(l.impl, info);
  }

  void BuildInfo() {
    if (lobes_.size() == 1) {
      info_ = lobes_[0].info;
      offsets_ = {0};
      weights_ = {-1};
      return;
    }
    info_ = ModelInfo{};
    info_.name = spec_;
    info_.reciprocal = true;
    info_.energy_conserving = false;  // a sum can exceed 1 even if every lobe does not
    std::size_t off = 0;
    for (const Lobe& l : lobes_) {
      offsets_.push_back(off);
      off += l.info.PackedSize();
      info_.reciprocal = info_.reciprocal && l.info.reciprocal;
      info_.summary += (info_.summary.empty() ? "" : " + ") + l.info.name;
      for (ParamInfo p : l.info.params) {
        p.name = l.prefix + "." + p.name;
        info_.params.push_back(p);
      }
      // A lobe that cannot vanish by its own parameters gets a weight, so
      // that every lobe of a sum can be switched off and a sum nests its
      // sub-sums. 1 (the default) is the lobe as it is alone.
      weights_.push_back(-1);
      if (!l.vanishes) {
        weights_.back() = static_cast<std::ptrdiff_t>(off++);
        info_.params.push_back({l.prefix + ".weight", 0.0, 10.0, 1.0, false,
                                "weight of the lobe in the sum (0 switches it off)"});
      }
    }
  }

  std::string spec_;
  std::vector<Lobe> lobes_;
  std::vector<std::size_t> offsets_;
  std::vector<std::ptrdiff_t> weights_;
  ModelInfo info_;
};

template <typename T>
std::unique_ptr<Bxdf<T>> Model::Make() const {
  if (lobes_.size() == 1) return MakeLobe<T>(lobes_[0], info_);
  std::vector<std::unique_ptr<Bxdf<T>>> parts;
  for (const Lobe& l : lobes_) parts.push_back(MakeLobe<T>(l, l.info));
  return std::make_unique<detail::SumBxdf<T>>(std::move(parts), offsets_, weights_, info_);
}

// Programs linking brdfkit::validate get Make<double> and Make<float>
// compiled once, in validate/models.cpp, instead of every registered model
// again in each of their translation units.
#ifdef BRDFKIT_PRECOMPILED_MODELS
extern template std::unique_ptr<Bxdf<double>> Model::Make<double>() const;
extern template std::unique_ptr<Bxdf<float>> Model::Make<float>() const;
#endif

}  // namespace brdfkit
