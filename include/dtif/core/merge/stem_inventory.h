// The merged stem inventory: trunks seen by many submaps and robots, fused into one entry per
// physical tree (issue #16).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "dtif/core/types.h"

namespace dtif {

struct StemFusionParams {
  double cluster_radius_m = 0.5;  ///< observations of one tree lie within this of its centre [m]
  double radius_rel_tol = 1.0;    ///< |r - r_cluster| <= max(abs, rel * r_cluster) ...
  double radius_abs_tol_m =
      0.2;  ///< ... to join a cluster (loose: one submap's radius can be far off) [m]
  int min_observations = 1;  ///< fewer contributing submaps: dropped (false trunks)
  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("cluster_radius_m", cluster_radius_m);
    v("radius_rel_tol", radius_rel_tol);
    v("radius_abs_tol_m", radius_abs_tol_m);
    v("min_observations", min_observations);
  }
};

/// One trunk of one submap, already in the component's map frame M.
struct StemObservation {
  int64_t submap = -1;
  int component = 0;
  double x = 0.0, y = 0.0, z = 0.0;  ///< centre and base elevation in M [m]
  double r = 0.0;                    ///< radius [m]
  bool base_seen = true;
};

/// One physical tree of the inventory, in its component's M.
struct MergedStem {
  int64_t stem_id = -1;  ///< 0.. in output order
  int component = 0;
  double x = 0.0, y = 0.0, z_base = 0.0;  ///< median of the observations [m]
  double dbh = 0.0;                       ///< 2 x median radius [m]
  int observations = 0;                   ///< contributing submaps
  std::string field_id;                   ///< the field stem map's tree id when matched
};

/// Clusters observations per component (greedy, nearest cluster centre within the radius and
/// a similar radius, at most one observation per submap in a cluster; then clusters closer than
/// the radius with no submap in common are joined) and fuses each cluster robustly: median
/// position and radius, base from the observations whose base was seen when there are any.
/// Deterministic: the output is ordered by component, then x, then y; stem ids follow that
/// order.
std::vector<MergedStem> fuseStems(const std::vector<StemObservation>& observations,
                                  const StemFusionParams& params);

}  // namespace dtif
