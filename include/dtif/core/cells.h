// Grid cell indices from coordinates that may come from outside (messages, files): a double
// beyond int64's range cast to int64 is undefined behaviour (UBSan found it at 1e30 m), and so
// is a left shift of a negative index. These saturate and pack without either.
#pragma once

#include <cmath>
#include <cstdint>

namespace dtif {

/// Cell indices are saturated here: 2^40 cells of 1 mm are still 10^9 m, beyond any survey.
constexpr int64_t kMaxCellIndex = int64_t{1} << 40;

/// floor(v) as an index, saturated to +-kMaxCellIndex; NaN gives 0.
inline int64_t cellIndex(double v) {
  if (std::isnan(v)) return 0;
  if (v >= static_cast<double>(kMaxCellIndex)) return kMaxCellIndex;
  if (v <= -static_cast<double>(kMaxCellIndex)) return -kMaxCellIndex;
  // The floor without libm's call (not inlined on baseline x86-64; the voxel filters take three
  // per return): the truncation, one lower where it rose above v.
  const int64_t i = static_cast<int64_t>(v);
  return i - (v < static_cast<double>(i));
}

/// One 64-bit key of a cell (ix, iy): ix in the high 32 bits, iy's low 32 bits in the low ones
/// (the bits `(ix << 32) ^ (iy & 0xffffffff)` would give, without the negative shift).
inline int64_t packCell(int64_t ix, int64_t iy) {
  return static_cast<int64_t>((static_cast<uint64_t>(ix) << 32) ^
                              (static_cast<uint64_t>(iy) & 0xffffffffULL));
}

}  // namespace dtif
