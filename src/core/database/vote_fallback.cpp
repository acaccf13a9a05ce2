// The vote fallback (see vote_fallback.h).
#include "dtif/core/database/vote_fallback.h"

#include <algorithm>

#include "dtif/core/matching/pair_vote.h"
#include "dtif/core/verification/lattice.h"

namespace dtif {

std::vector<Correspondence> voteCorrespondences(const Descriptor& q, const Descriptor& c,
                                                const LoopDetectorParams& params, Rejection* why) {
  constexpr int kPeaks = 4;
  const std::vector<VotePeak> peaks = votePoses(q, c, params.matcher, kPeaks);
  const double radius = params.verification.match_radius_m;
  std::vector<Fit> fits;
  if (!peaks.empty()) {
    const RefineTargets targets(c, radius);  // one grid for the peaks' fits
    for (const VotePeak& pk : peaks) {
      Pose T = Pose::Identity();
      T.linear() = rotZ(pk.yaw);
      T.translation() = Eigen::Vector3d(pk.t.x(), pk.t.y(), 0.0);
      fits.push_back(fitPose(q, c, targets, T, radius));
    }
  }
  size_t best = 0;
  for (size_t k = 1; k < fits.size(); ++k)
    if (fits[k].score > fits[best].score) best = k;
  if (fits.empty() || fits[best].score <= 0.0) {
    *why = Rejection::kNoVotedPose;
    return {};
  }
  // Distinct: some query trunk lands more than two match radii away from where the best puts it.
  double runner_up = 0.0;
  for (size_t k = 0; k < fits.size(); ++k) {
    if (k == best) continue;
    double moved = 0.0;
    for (const TrunkLandmark& t : q.trunks) {
      const Eigen::Vector3d p(t.x, t.y, 0.0);
      moved = std::max(moved, ((fits[k].T * p) - (fits[best].T * p)).head<2>().norm());
    }
    if (moved > 2.0 * radius) runner_up = std::max(runner_up, fits[k].score);
  }
  if (runner_up > params.verification.max_ambiguity * fits[best].score) {
    *why = Rejection::kAmbiguousVotes;
    return {};
  }
  // The best fit's own refined pairs (fitPose already ran the guided refinement). Radii are not
  // compared (see votePoses): the pairs' geometry carries the evidence.
  std::vector<Correspondence> corrs;
  for (const auto& [i, j] : fits[best].pairs) {
    const TrunkLandmark &a = q.trunks[i], &b = c.trunks[j];
    Correspondence k;
    k.iq = i, k.ic = j;
    k.pq = Eigen::Vector3d(a.x, a.y, a.z);
    k.pc = Eigen::Vector3d(b.x, b.y, b.z);
    k.z_ok = a.base_seen && b.base_seen;
    corrs.push_back(k);
  }
  if (static_cast<int>(corrs.size()) < params.verification.min_hypothesis_inliers) {
    *why = Rejection::kFewVotedPairs;
    return {};
  }
  return corrs;
}

}  // namespace dtif
