// The stages of votePoses (pair_vote.h), in the order it runs them: the trunk pairs of either
// side, the vote accumulator over (yaw, x, y) bins, the seeds' neighbourhood scores, and
// non-maximum suppression into peaks. Exposed for unit tests; callers use votePoses. All pure
// and thread-safe.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/matching/matcher.h"
#include "dtif/core/matching/pair_vote.h"

namespace dtif {
namespace pair_vote_stages {

/// A trunk pair i < j of one descriptor.
struct TrunkPair {
  double len;           ///< [m]
  double cos_a, sin_a;  ///< direction of i -> j
  Eigen::Vector2d mid;  ///< midpoint [m]
  int i, j;
};

/// The pairs of d's trunks from 1.5 m (shorter ones fix the yaw too poorly) to max_len [m],
/// sorted by length, then i, then j. Non-finite trunks form no pair.
std::vector<TrunkPair> trunkPairs(const Descriptor& d, double max_len);

/// One (yaw, x, y) bin of the accumulator: its indices, the votes and the sums of their poses.
struct VoteBin {
  int64_t iyaw = 0, ix = 0, iy = 0;
  double count = 0.0, cos_sum = 0.0, sin_sum = 0.0;
  Eigen::Vector2d t_sum = Eigen::Vector2d::Zero();
};

/// The vote accumulator: bins of yaw_bin [rad] x xy_bin [m] x xy_bin [m], yaw wrapping at n_yaw.
/// A flat open-addressing table over the packed indices (a submap pair casts ~10^5 votes: one
/// allocation, not one per bin).
struct VoteAccumulator {
  int64_t n_yaw = 1;
  double yaw_bin = 0.0;       ///< [rad]
  double xy_bin = 0.0;        ///< [m]
  std::vector<VoteBin> bins;  ///< the bins with votes, first vote first

  /// The bin at (iyaw, ix, iy), nullptr when it has no vote.
  const VoteBin* find(int64_t iyaw, int64_t ix, int64_t iy) const;
  /// The bin at (iyaw, ix, iy), added when it has no vote yet.
  VoteBin& at(int64_t iyaw, int64_t ix, int64_t iy);
  /// Sizes the table for up to n bins (before the first at()).
  void reserve(size_t n);

 private:
  size_t slot(int64_t key) const;
  /// A table for up to n bins holding the current ones.
  void rehash(size_t n);
  /// Per slot its packed indices (-1: free) and its bin in bins, side by side: a probe reads
  /// one cache line, not one in each of two arrays.
  struct Slot {
    int64_t key = -1;
    int64_t index = -1;
  };
  std::vector<Slot> slots_;
  size_t mask_ = 0;
};

/// Every length-compatible pair of a query pair and a candidate pair (Cons_l of Eq. 3.4 on the
/// pair lengths; both lists sorted by length) votes twice: for the pose pairing i with i and j
/// with j, and for the one turned by pi. Translations beyond the bin packing range do not vote.
VoteAccumulator accumulateVotes(const std::vector<TrunkPair>& pq, const std::vector<TrunkPair>& pc,
                                const MatcherParams& params);
/// The same, into *acc (its contents replaced; its memory reused): votePoses keeps one per
/// thread, as a fresh table of ~1.5 MB was mapped, page-faulted and unmapped per candidate.
void accumulateVotes(const std::vector<TrunkPair>& pq, const std::vector<TrunkPair>& pc,
                     const MatcherParams& params, VoteAccumulator* acc);

/// A seed bin and the sums over its 3 x 3 x 3 neighbourhood (yaw wraps around).
struct ScoredSeed {
  const VoteBin* seed;  ///< into the accumulator's bins
  VoteBin sum;          ///< indices unset; count and sums of the neighbourhood
};

/// The 64 fullest bins (ties by position, so the result does not depend on hashing) with their
/// neighbourhood sums, strongest neighbourhood first (stable).
std::vector<ScoredSeed> scoreSeeds(const VoteAccumulator& acc);

/// Non-maximum suppression over the scored seeds: a seed within one bin of a stronger taken one
/// is the same pose; stops below 4 votes or at max_peaks peaks. A peak's pose is the mean of
/// its neighbourhood's proposals.
std::vector<VotePeak> selectPeaks(const std::vector<ScoredSeed>& scored, int64_t n_yaw,
                                  int max_peaks);

}  // namespace pair_vote_stages
}  // namespace dtif
