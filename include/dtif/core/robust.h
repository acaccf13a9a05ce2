// Robust weights shared by the stages of the core.
#pragma once

#include <cmath>

namespace dtif {

/// Tukey biweight (1 - (r / c)^2)^2 of a residual r, 0 from |r| >= c on.
inline double tukeyWeight(double r, double c) {
  if (std::abs(r) >= c) return 0.0;
  const double u = r / c;
  const double t = 1.0 - u * u;
  return t * t;
}

/// The same biweight of a residual given as its square r2 = r^2 (no square root where a
/// nearest-neighbour search already returns squared distances).
inline double tukeyWeightOfSquare(double r2, double c) {
  const double u = r2 / (c * c);
  return u < 1.0 ? (1.0 - u) * (1.0 - u) : 0.0;
}

}  // namespace dtif
