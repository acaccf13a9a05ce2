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
  double angle;         ///< that direction [rad] (atan2)
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

/// votePoses' accumulator: the bins of VoteAccumulator with only their vote counts, and each
/// vote's bin in vote order. Only the bins around the seeds are ever summed (scoreSeeds casts
/// their votes again): most of a submap pair's votes fall into bins of their own, and a full
/// VoteBin per bin (64 bytes, plus its slot) cost more than casting the vote. The few bins of
/// two votes or more are listed, and the votes counted per yaw bin, so that the seeds are found
/// without a pass over the table.
class VoteCounts {
 public:
  /// Pairs casting more votes take VoteAccumulator (a count takes 20 bits of a slot).
  static constexpr size_t kMaxVotes = (size_t{1} << 20) - 1;
  static constexpr int kCountBits = 20;
  static constexpr uint64_t kCountMask = (uint64_t{1} << kCountBits) - 1;
  /// The bin of a vote out of the packing range (in no bin, above every bin).
  static constexpr uint64_t kSkipped = ~uint64_t{0};

  int64_t n_yaw = 1;
  double yaw_bin = 0.0;  ///< [rad]
  double xy_bin = 0.0;   ///< [m]

  /// Empties the table and sizes it for up to n <= kMaxVotes votes (no growth while voting).
  void reset(size_t n);
  /// One vote into bin (countVotes' packing: nonzero, yaw bin in the bits from 32), counted
  /// by count().
  void add(uint64_t bin) { votes_.push_back(bin); }
  /// A vote out of the packing range: in the vote order, in no bin.
  void skip() { votes_.push_back(kSkipped); }
  /// Counts the votes added since reset() into the table, once. Apart from casting them: the
  /// casting loop then waits on no table (votePoses 4 % faster; a prefetch ahead gained nothing).
  void count();
  /// Votes in bin.
  uint32_t votesIn(uint64_t bin) const {
    const size_t f = filterBit(bin);
    if (!(filter_[f >> 6] >> (f & 63) & 1)) return 0;
    for (size_t k = home(bin);; k = (k + 1) & mask_) {
      const uint64_t s = slots_[k];
      if (s == 0) return 0;
      if (s >> kCountBits == bin) return static_cast<uint32_t>(s & kCountMask);
    }
  }
  /// The bins of two votes or more, each as bin << kCountBits | count.
  std::vector<uint64_t> multiVoteBins() const;
  /// Votes per yaw bin.
  const std::vector<uint32_t>& yawVotes() const { return yaw_votes_; }
  /// Each vote's bin (kSkipped: out of range), in vote order.
  const std::vector<uint64_t>& votes() const { return votes_; }
  /// Memory held [bytes].
  size_t bytes() const;

 private:
  size_t home(uint64_t bin) const {
    return static_cast<size_t>((bin * 0x9E3779B97F4A7C15ull) >> shift_);
  }
  /// A bin's bit in filter_ (16 per slot).
  size_t filterBit(uint64_t bin) const {
    return static_cast<size_t>((bin * 0x9E3779B97F4A7C15ull) >> (shift_ - 4));
  }
  std::vector<uint64_t> slots_;  ///< 0 (free) or bin << kCountBits | count
  /// A bit set per bin with votes: most bins asked for (the seeds' neighbours) have none, and
  /// one well-predicted bit test says so where a probe of the table mispredicts.
  std::vector<uint64_t> filter_;
  std::vector<uint64_t> votes_;
  std::vector<uint32_t> multi_;  ///< slots of the bins of two votes or more
  std::vector<uint32_t> yaw_votes_;
  size_t mask_ = 0;
  int shift_ = 64;
};

/// The votes of accumulateVotes counted into *counts (its contents replaced; its memory
/// reused). False, counting none, when there would be over VoteCounts::kMaxVotes.
bool countVotes(const std::vector<TrunkPair>& pq, const std::vector<TrunkPair>& pc,
                const MatcherParams& params, VoteCounts* counts);

/// A seed bin and the sums over its 3 x 3 x 3 neighbourhood (yaw wraps around).
struct ScoredSeed {
  const VoteBin* seed;  ///< into the accumulator's bins
  VoteBin sum;          ///< indices unset; count and sums of the neighbourhood
};

/// The 64 fullest bins (ties by position, so the result does not depend on hashing) with their
/// neighbourhood sums, strongest neighbourhood first (stable).
std::vector<ScoredSeed> scoreSeeds(const VoteAccumulator& acc);

/// scoreSeeds on the votes that countVotes(pq, pc, params) counted: the same seeds, sums and
/// order as on accumulateVotes' accumulator. The seeds' bins (indices and counts) go to
/// *seeds, which the result points into.
std::vector<ScoredSeed> scoreSeeds(const VoteCounts& counts, const std::vector<TrunkPair>& pq,
                                   const std::vector<TrunkPair>& pc, const MatcherParams& params,
                                   std::vector<VoteBin>* seeds);

/// Non-maximum suppression over the scored seeds: a seed within one bin of a stronger taken one
/// is the same pose; stops below 4 votes or at max_peaks peaks. A peak's pose is the mean of
/// its neighbourhood's proposals.
std::vector<VotePeak> selectPeaks(const std::vector<ScoredSeed>& scored, int64_t n_yaw,
                                  int max_peaks);

}  // namespace pair_vote_stages
}  // namespace dtif
