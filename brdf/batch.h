// Batch evaluation: f_r of n direction pairs in one call, for numpy arrays,
// tables and benchmarks.
//
// Directions are rows of three scalars (x, y, z), the layout of a C-ordered
// (n, 3) array; a row stride of 0 repeats one direction for every pair (a
// broadcast). Values go to out[3 k + c]. Bxdf<T>::EvalBatch reaches a
// model's batch code in one virtual call: the model's own EvalBatch member
// when it has one (a vectorised kernel, run through RunBatchKernel below),
// otherwise the generic loop here, which calls the model's templated Eval
// inlined (no virtual call per pair, but the compiler does not vectorise it:
// the models' early returns and guarded divisions are branches).
#pragma once

#include "brdf/core.h"

#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <type_traits>

namespace brdfkit {

template <typename M, typename T>
void EvalBatch(const M& model, const T* p, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride,
               std::size_t n, T* out) {
  for (std::size_t k = 0; k < n; ++k) {
    const T* a = wi + k * wi_stride;
    const T* b = wo + k * wo_stride;
    const Rgb<T> f = model.template Eval<T>(p, Vec3<T>(a[0], a[1], a[2]), Vec3<T>(b[0], b[1], b[2]));
    out[3 * k] = f[0];
    out[3 * k + 1] = f[1];
    out[3 * k + 2] = f[2];
  }
}

// --- vectorised kernels --------------------------------------------------
//
// A kernel is a small copyable object with
//   void operator()(const T* wi, const T* wo, T* out) const
// for one pair (out: three values), written without branches: every value
// is computed for every pair and the ones that do not apply (directions
// below the horizon) are discarded by Select, a bitwise blend. GCC 12 then
// vectorises the loop over pairs (checked with -fopt-info-vec) when sqrt
// does not set errno (the project builds with -fno-math-errno; without it
// the kernels give the same values, unvectorised). A conditional
// expression `c ? x : 0` would not do: GCC sinks the computation of x into
// a branch, which it may not turn back into straight-line code because x
// could raise a floating-point exception (-ftrapping-math, the default).

// c ? a : b as a bitwise blend: both operands are always computed.
template <typename T>
  requires std::is_floating_point_v<T>
inline T Select(bool c, T a, T b) {
  using U = std::conditional_t<sizeof(T) == 8, std::uint64_t, std::uint32_t>;
  const U m = U(0) - U(c);
  return std::bit_cast<T>((std::bit_cast<U>(a) & m) | (std::bit_cast<U>(b) & ~m));
}

// Instruction sets the kernels are compiled for. On x86-64 (GCC or Clang)
// each kernel loop exists three times: for the baseline (SSE2), for AVX2 with
// FMA and for AVX-512 (F, VL, DQ); the widest the processor has is taken at
// run time. FMA contraction in the wider versions changes the last bits of
// a value, nothing more. Elsewhere there is the baseline only.
enum class BatchIsa { kBaseline = 0, kAvx2 = 1, kAvx512 = 2 };

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define BRDFKIT_BATCH_X86 1
#endif

// The widest instruction set this processor runs.
inline BatchIsa DetectedBatchIsa() {
#ifdef BRDFKIT_BATCH_X86
  static const BatchIsa isa = [] {
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
        __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
      return BatchIsa::kAvx512;
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return BatchIsa::kAvx2;
    return BatchIsa::kBaseline;
  }();
  return isa;
#else
  return BatchIsa::kBaseline;
#endif
}

namespace detail {
inline std::atomic<int>& BatchIsaLimit() {
  static std::atomic<int> limit{static_cast<int>(BatchIsa::kAvx512)};
  return limit;
}
}  // namespace detail

// Caps the instruction set the kernels use (tests run every version the
// processor has; kAvx512 lifts the cap). Returns the set now in use.
inline BatchIsa LimitBatchIsa(BatchIsa isa) {
  detail::BatchIsaLimit().store(static_cast<int>(isa));
  return std::min(isa, DetectedBatchIsa());
}

inline BatchIsa ActiveBatchIsa() {
  return std::min(static_cast<BatchIsa>(detail::BatchIsaLimit().load(std::memory_order_relaxed)), DetectedBatchIsa());
}

namespace detail {

// Strides as template arguments (3: rows of an (n, 3) array, 0: one
// direction for all) let the compiler see the access pattern; kAnyStride
// takes them at run time.
inline constexpr std::size_t kAnyStride = ~std::size_t(0);

template <std::size_t SA, std::size_t SB, typename K, typename T>
[[gnu::always_inline]] inline void KernelLoop(const K k, const T* wi, std::size_t sa, const T* wo, std::size_t sb,
                                              std::size_t n, T* out) {
  if constexpr (SA != kAnyStride) sa = SA;
  if constexpr (SB != kAnyStride) sb = SB;
  for (std::size_t j = 0; j < n; ++j) k(wi + j * sa, wo + j * sb, out + 3 * j);
}

template <std::size_t SA, std::size_t SB, typename K, typename T>
[[gnu::noinline]] void KernelBaseline(const K k, const T* wi, std::size_t sa, const T* wo, std::size_t sb,
                                      std::size_t n, T* out) {
  KernelLoop<SA, SB>(k, wi, sa, wo, sb, n, out);
}

#ifdef BRDFKIT_BATCH_X86
template <std::size_t SA, std::size_t SB, typename K, typename T>
[[gnu::noinline, gnu::target("avx2,fma")]] void KernelAvx2(const K k, const T* wi, std::size_t sa, const T* wo,
                                                          std::size_t sb, std::size_t n, T* out) {
  KernelLoop<SA, SB>(k, wi, sa, wo, sb, n, out);
}

template <std::size_t SA, std::size_t SB, typename K, typename T>
[[gnu::noinline, gnu::target("avx512f,avx512vl,avx512dq,avx2,fma")]] void KernelAvx512(
    const K k, const T* wi, std::size_t sa, const T* wo, std::size_t sb, std::size_t n, T* out) {
  KernelLoop<SA, SB>(k, wi, sa, wo, sb, n, out);
}
#endif

template <std::size_t SA, std::size_t SB, typename K, typename T>
void RunKernelIsa(const K& k, const T* wi, std::size_t sa, const T* wo, std::size_t sb, std::size_t n, T* out) {
#ifdef BRDFKIT_BATCH_X86
  switch (ActiveBatchIsa()) {
    case BatchIsa::kAvx512:
      return KernelAvx512<SA, SB>(k, wi, sa, wo, sb, n, out);
    case BatchIsa::kAvx2:
      return KernelAvx2<SA, SB>(k, wi, sa, wo, sb, n, out);
    case BatchIsa::kBaseline:
      break;
  }
#endif
  KernelBaseline<SA, SB>(k, wi, sa, wo, sb, n, out);
}

}  // namespace detail

// Runs kernel k over n pairs (the layout of EvalBatch above).
template <typename K, typename T>
void RunBatchKernel(const K& k, const T* wi, std::size_t wi_stride, const T* wo, std::size_t wo_stride, std::size_t n,
                    T* out) {
  using detail::kAnyStride;
  if (wi_stride == 3 && wo_stride == 3) return detail::RunKernelIsa<3, 3>(k, wi, 3, wo, 3, n, out);
  if (wi_stride == 0 && wo_stride == 3) return detail::RunKernelIsa<0, 3>(k, wi, 0, wo, 3, n, out);
  if (wi_stride == 3 && wo_stride == 0) return detail::RunKernelIsa<3, 0>(k, wi, 3, wo, 0, n, out);
  detail::RunKernelIsa<kAnyStride, kAnyStride>(k, wi, wi_stride, wo, wo_stride, n, out);
}

}  // namespace brdfkit
