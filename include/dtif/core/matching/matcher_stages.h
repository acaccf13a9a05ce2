// The stages of buildCorrespondences (matcher.h), paper Algorithm 1, in the order it runs them:
// histogram screening (lines 4-7), edge-radius consistency (Eq. 3.4) and vertex support
// (Eqs. 3.5-3.7), then the weighted correspondences (Eqs. 3.8-3.10). Exposed for unit tests;
// callers use buildCorrespondences. All pure and thread-safe.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/matching/matcher.h"

namespace dtif {
namespace matcher_stages {

/// Alg. 1 lines 4-7: sets stats->edge_hist_sim and radius_hist_sim; false (and
/// stats->screened_out) when either is below its threshold.
bool passesScreening(const Descriptor& query, const Descriptor& candidate,
                     const MatcherParams& params, MatchStats* stats);

/// Eq. (3.4): bit a set when canonical edge a of q and c passes Cons_l and both its endpoints
/// pass Cons_r (chi_a = 1).
int consistentEdges(const Triangle& q, const Triangle& c, const MatcherParams& params);

/// Eq. (3.5): the support matrices E^s and E^w, flat nq x nc (row = query trunk).
struct VertexSupport {
  size_t nq = 0, nc = 0;
  std::vector<uint16_t> strong;   ///< E^s (saturates at 65535)
  std::vector<uint16_t> weak;     ///< E^w (saturates at 65535)
  std::vector<uint32_t> touched;  ///< flat indices of the non-zero entries, ascending
};

/// Eqs. (3.4)-(3.7) over the triangle pairs whose longest edges are Cons_l-consistent (tc
/// sorted by len[0]): a fully consistent pair gives strong support to its three vertex pairs,
/// a partly consistent pair of Delaunay faces weak support to the ends of its consistent
/// edges. Adds the pairs visited to *triangle_pairs. bq: consistencyBounds(tq, params),
/// computed here when null.
VertexSupport accumulateSupport(const std::vector<MatchTriangle>& tq,
                                const std::vector<MatchTriangle>& tc, size_t nq, size_t nc,
                                const MatcherParams& params, size_t* triangle_pairs,
                                const std::vector<ConsistencyBounds>* bq = nullptr);

/// Eqs. (3.8)-(3.10): the vertex pairs with strong support or enough weak support, weighted
/// (Eq. 3.9), heaviest first (ties by index), at most params.max_correspondences.
std::vector<Correspondence> weightedCorrespondences(const VertexSupport& support,
                                                    const Descriptor& query,
                                                    const Descriptor& candidate,
                                                    const MatcherParams& params);

}  // namespace matcher_stages
}  // namespace dtif
