// Wall-clock timing of the pipeline's stages (the t_*_ms columns and QueryStats).
#pragma once

#include <chrono>

namespace dtif {

/// Milliseconds elapsed since t0 on the steady clock [ms].
inline double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace dtif
