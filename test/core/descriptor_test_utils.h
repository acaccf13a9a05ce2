// Structural faults of a descriptor that every receiving path must reject in the same words
// (decodeDescriptor, the ROS conversion), shared by their tests.
#pragma once

#include <algorithm>
#include <functional>
#include <limits>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"

namespace dtif::test {

/// Each entry breaks one check of checkDescriptor on a valid descriptor with at least 5 faces.
inline std::vector<std::function<void(Descriptor&)>> descriptorCorruptions() {
  constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();
  return {
      [](Descriptor& d) { d.trunks[3].r = kNaNf; },
      [](Descriptor& d) { d.trunks[1].x = kNaNf; },
      [](Descriptor& d) { d.trunks[2].r = -0.1; },
      [](Descriptor& d) { d.triangles[4].v[1] = static_cast<int>(d.trunks.size()); },
      [](Descriptor& d) { d.triangles[2].v[2] = d.triangles[2].v[0]; },
      [](Descriptor& d) { std::fill(d.radius_hist.begin(), d.radius_hist.end(), 0.0f); },
      [](Descriptor& d) { std::fill(d.edge_hist.begin(), d.edge_hist.end(), 0.0f); },
  };
}

}  // namespace dtif::test
