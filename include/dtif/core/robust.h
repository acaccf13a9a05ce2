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

}  // namespace dtif
