// Run-time choice of the AVX2 forms of extraction's per-point passes. The build targets baseline
// x86-64 (no -march, STYLE.md), so those forms are compiled with a per-function target and taken
// only on a CPU that has AVX2. They give the same bits as the baseline forms: the same IEEE
// operations in the same order per point, and no "fma" target (a fused multiply-add rounds
// once, not twice).
#pragma once

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define DTIF_AVX2_PATHS 1
/// Marks a function compiled for AVX2 (and what it inlines must carry it too).
#define DTIF_TARGET_AVX2 __attribute__((target("avx2")))
#else
#define DTIF_AVX2_PATHS 0
#endif

namespace dtif {

/// Whether the passes take their AVX2 forms: the CPU has AVX2 and allowAvx2(false) was not
/// called. Thread-safe.
bool useAvx2();
/// Allows (the default) or forbids the AVX2 forms, process-wide: tests compare both forms.
/// Thread-safe; a pass already running keeps its form.
void allowAvx2(bool allow);

}  // namespace dtif
