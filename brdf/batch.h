// Batch evaluation: f_r of n direction pairs in one call, for numpy arrays,
// tables and benchmarks.
//
// Directions are rows of three scalars (x, y, z), the layout of a C-ordered
// (n, 3) array; a row stride of 0 repeats one direction for every pair (a
// broadcast). Values go to out[3 k + c]. The loop calls the model's own
// templated Eval, inlined: no virtual call per pair, and the compiler sees
// the whole loop body (Bxdf<T>::EvalBatch reaches it in one virtual call).
#pragma once

#include "brdf/core.h"

#include <cstddef>

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

}  // namespace brdfkit
