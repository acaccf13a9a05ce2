// Run-time choice of the AVX2 forms of extraction's per-point passes. The build targets baseline
// x86-64 (no -march, STYLE.md), so those forms are compiled with a per-function target and taken
// only on a CPU that has AVX2. They give the same bits as the baseline forms: the same IEEE
// operations in the same order per point, and no "fma" target (a fused multiply-add rounds
// once, not twice).
#pragma once

#include <cstdint>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define DTIF_AVX2_PATHS 1
/// Marks a function compiled for AVX2 (and what it inlines must carry it too).
#define DTIF_TARGET_AVX2 __attribute__((target("avx2")))
#else
#define DTIF_AVX2_PATHS 0
#endif

#if DTIF_AVX2_PATHS
#include <immintrin.h>
#endif

namespace dtif {

/// Whether the passes take their AVX2 forms: the CPU has AVX2 and allowAvx2(false) was not
/// called. Thread-safe.
bool useAvx2();
/// Allows (the default) or forbids the AVX2 forms, process-wide: tests compare both forms.
/// Thread-safe; a pass already running keeps its form.
void allowAvx2(bool allow);

#if DTIF_AVX2_PATHS
/// For each mask of four lanes, its set lanes in order (then zeros) and their count: packs the
/// lanes a test keeps (a permute by lane[mask], then count[mask] of them stored).
struct MaskLanes {
  alignas(16) int32_t lane[16][4];
  int count[16];
};
constexpr MaskLanes maskLanes() {
  MaskLanes t{};
  for (int m = 0; m < 16; ++m) {
    for (int j = 0; j < 4; ++j) {
      if ((m >> j) & 1) t.lane[m][t.count[m]++] = j;
    }
  }
  return t;
}
constexpr MaskLanes kLanes = maskLanes();  // internal: no load of its address from the GOT

/// Four (x, y, z) triples, xyz[0..11], as lanes of x, of y and of z (the 48 bytes, no more).
DTIF_TARGET_AVX2 inline void deinterleave4(const float* xyz, __m128* x, __m128* y, __m128* z) {
  const __m128 m0 = _mm_loadu_ps(xyz), m1 = _mm_loadu_ps(xyz + 4), m2 = _mm_loadu_ps(xyz + 8);
  // m0 = x0 y0 z0 x1, m1 = y1 z1 x2 y2, m2 = z2 x3 y3 z3.
  const __m128 u = _mm_shuffle_ps(m1, m2, _MM_SHUFFLE(1, 1, 2, 2));  // x2 x2 x3 x3
  const __m128 v = _mm_shuffle_ps(m0, m1, _MM_SHUFFLE(0, 0, 1, 1));  // y0 y0 y1 y1
  const __m128 w = _mm_shuffle_ps(m1, m2, _MM_SHUFFLE(2, 2, 3, 3));  // y2 y2 y3 y3
  const __m128 a = _mm_shuffle_ps(m0, m1, _MM_SHUFFLE(1, 1, 2, 2));  // z0 z0 z1 z1
  *x = _mm_shuffle_ps(m0, u, _MM_SHUFFLE(2, 0, 3, 0));
  *y = _mm_shuffle_ps(v, w, _MM_SHUFFLE(2, 0, 2, 0));
  *z = _mm_shuffle_ps(a, m2, _MM_SHUFFLE(3, 0, 2, 0));
}
#endif

}  // namespace dtif
