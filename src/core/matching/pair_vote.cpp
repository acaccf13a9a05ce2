// Pose voting over trunk pairs (see pair_vote.h).
#include "dtif/core/matching/pair_vote.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "dtif/core/matching/pair_vote_stages.h"

namespace dtif {
namespace {

constexpr double kTwoPi = 6.283185307179586;
/// Shorter pairs fix the yaw too poorly (2 cm of centre noise turn a 1.5 m pair by ~1 deg).
constexpr double kMinPairM = 1.5;
/// Bins ranked by their own count before the neighbourhood sums; enough for a few peaks.
constexpr size_t kSeedBins = 64;
/// A pose that fewer pairs propose is no peak: three common trunks give three votes by chance
/// alignment far too often, four in a cluster give six.
constexpr double kMinPeakVotes = 4.0;

/// floor(v) as an integer for |v| < 2^62 (the votes' bins: |v| < 3e4), without the libm call:
/// truncation, one less for a negative v that is not an integer. The same value as
/// static_cast<int64_t>(std::floor(v)).
inline int64_t floorIndex(double v) {
  const int64_t t = static_cast<int64_t>(v);
  return t - static_cast<int64_t>(v < static_cast<double>(t));
}

/// A vote's yaw is taken as the difference of its pairs' directions (one atan2 per pair, not
/// per vote), within ~1e-15 rad of atan2(sy, cy) of the vote's turn and far within
/// kApproxYawErr of it: it only picks the yaw bin, and votes within kYawHair of a bin edge take
/// atan2's.
constexpr double kApproxYawErr = 2e-5;
constexpr double kYawHair = 5.0 * kApproxYawErr;  // [rad]

/// The vote accumulator's yaw bins: n_yaw of yaw_bin [rad] from 0, a yaw in [-pi, pi] or
/// [0, 2 pi) wrapped into them.
struct YawBins {
  YawBins(int64_t n, double bin)
      : n_yaw(n), yaw_bin(bin), per_rad(1.0 / bin), hair(kYawHair / bin) {}
  int64_t n_yaw;
  double yaw_bin;
  double per_rad;  ///< 1 / yaw_bin, for `near` (its rounding is far inside the hair)
  double hair;     ///< kYawHair in bins
  int64_t exact(double yaw) const {
    if (yaw < 0.0) yaw += kTwoPi;
    return std::min<int64_t>(static_cast<int64_t>(yaw / yaw_bin), n_yaw - 1);
  }
  /// The bin of an approximate yaw `near` (within kApproxYawErr of the exact one) when it lies
  /// clear of the bin edges (and of the wrap), else exact(yaw()): the bin of the exact yaw
  /// either way.
  template <class Yaw>
  int64_t of(double near, const Yaw& yaw) const {
    int64_t bin;
    return clearOf(near, &bin) ? bin : exact(yaw());
  }
  /// Whether `near` lies clear of the bin edges and of the wrap; then its bin is *bin.
  bool clearOf(double near, int64_t* bin) const {
    const double pos = (near < 0.0 ? near + kTwoPi : near) * per_rad;
    const double frac = pos - static_cast<double>(floorIndex(pos));
    *bin = static_cast<int64_t>(pos);
    return frac > hair && frac < 1.0 - hair && pos > 0.0 && pos < static_cast<double>(n_yaw) - hair;
  }
  /// The bin of yaw + pi for a yaw in bin `bin` clear of the edges, when n_yaw is even (its
  /// edges turned by pi are edges again), else -1.
  int64_t halfTurn(int64_t bin) const {
    if (n_yaw % 2 != 0) return -1;
    return bin < n_yaw / 2 ? bin + n_yaw / 2 : bin - n_yaw / 2;
  }
};

inline int64_t packBin(int64_t iyaw, int64_t ix, int64_t iy) {
  // 12 bits of yaw (up to 4096 bins), 26 bits per translation axis (+-33,000 bins).
  constexpr int64_t kHalf = int64_t{1} << 25;
  return (iyaw << 52) | ((ix + kHalf) << 26) | (iy + kHalf);
}

/// A bin of VoteCounts: 12 bits of yaw, 16 per translation axis (|ix|, |iy| < 3e4 by max_t),
/// ordered as (iyaw, ix, iy) and never 0.
inline uint64_t compactBin(int64_t iyaw, int64_t ix, int64_t iy) {
  constexpr int64_t kHalf = int64_t{1} << 15;
  return static_cast<uint64_t>((iyaw << 32) | ((ix + kHalf) << 16) | (iy + kHalf));
}
inline void unpackCompactBin(uint64_t bin, pair_vote_stages::VoteBin* b) {
  constexpr int64_t kHalf = int64_t{1} << 15;
  b->iyaw = static_cast<int64_t>(bin >> 32);
  b->ix = static_cast<int64_t>((bin >> 16) & 0xFFFF) - kHalf;
  b->iy = static_cast<int64_t>(bin & 0xFFFF) - kHalf;
}

/// The accumulator's bins for params.
struct VoteGrid {
  int64_t n_yaw;
  double yaw_bin;  ///< [rad]
  double xy_bin;   ///< [m]
};
VoteGrid voteGrid(const MatcherParams& params) {
  const int64_t n_yaw = std::clamp<int64_t>(std::llround(360.0 / params.vote_yaw_bin_deg), 1, 4095);
  return {n_yaw, kTwoPi / static_cast<double>(n_yaw), params.vote_xy_bin_m};
}

/// f(a, b) for the length-compatible candidate pairs b of every query pair a, by a sliding
/// window over both sorted lists (Cons_l). The radii do not vote: where stems are partly hidden
/// their fitted radii are off by half or more (dense_slope: 9 of 32 pairs of common trunks pass
/// Cons_r on both ends).
template <class F>
void forCompatible(const std::vector<pair_vote_stages::TrunkPair>& pq,
                   const std::vector<pair_vote_stages::TrunkPair>& pc, const MatcherParams& params,
                   const F& f) {
  size_t lo = 0;
  for (const pair_vote_stages::TrunkPair& a : pq) {
    const double tol = std::max(params.edge_abs_tol_m, params.edge_rel_tol * a.len);
    while (lo < pc.size() && pc[lo].len < a.len - tol) ++lo;
    for (size_t k = lo; k < pc.size() && pc[k].len <= a.len + tol; ++k) f(a, pc[k]);
  }
}

size_t countCompatible(const std::vector<pair_vote_stages::TrunkPair>& pq,
                       const std::vector<pair_vote_stages::TrunkPair>& pc,
                       const MatcherParams& params) {
  size_t n = 0;
  forCompatible(pq, pc, params, [&](const auto&, const auto&) { ++n; });
  return n;
}

/// The turn (cos cy, sin sy) of a pair's proposal: yaw = direction of b - direction of a pairs
/// a.i with b.i and a.j with b.j; yaw + pi (-cy, -sy) pairs a.i with b.j and a.j with b.i.
inline void pairTurn(const pair_vote_stages::TrunkPair& a, const pair_vote_stages::TrunkPair& b,
                     double* cy, double* sy) {
  *cy = b.cos_a * a.cos_a + b.sin_a * a.sin_a;
  *sy = b.sin_a * a.cos_a - b.cos_a * a.sin_a;
}

/// A proposal's translation: T_c_q turns by (cy, sy) and maps the query pair's midpoint mq
/// onto the candidate's mc.
inline Eigen::Vector2d proposalT(double cy, double sy, const Eigen::Vector2d& mq,
                                 const Eigen::Vector2d& mc) {
  return Eigen::Vector2d(mc.x() - (cy * mq.x() - sy * mq.y()),
                         mc.y() - (sy * mq.x() + cy * mq.y()));
}

/// f(iyaw, ix, iy, cy, sy, t) for every vote, skip() for one out of the packing range: two per
/// length-compatible pair, in one fixed order (accumulateVotes and scoreSeeds(VoteCounts) sum
/// a bin's votes in it, bit for bit the same).
template <class F, class Skip>
void forEachVote(const std::vector<pair_vote_stages::TrunkPair>& pq,
                 const std::vector<pair_vote_stages::TrunkPair>& pc, const MatcherParams& params,
                 const VoteGrid& grid, const F& f, const Skip& skip) {
  const double xy_bin = grid.xy_bin;
  // Translations beyond the packing range are no poses of overlapping submaps.
  const double max_t = 3.0e4 * xy_bin;
  // Dividing by a power of two (0.5 m bins) is multiplying by its exact inverse, bit for bit.
  int exponent = 0;
  const bool pow2 = std::frexp(xy_bin, &exponent) == 0.5;
  const double per_m = 1.0 / xy_bin;
  auto cell = [&](double v) { return floorIndex(pow2 ? v * per_m : v / xy_bin); };
  auto vote = [&](int64_t iyaw, double cy, double sy, const Eigen::Vector2d& mq,
                  const Eigen::Vector2d& mc) {
    const Eigen::Vector2d t = proposalT(cy, sy, mq, mc);
    if (!(std::abs(t.x()) < max_t && std::abs(t.y()) < max_t)) return skip();
    f(iyaw, cell(t.x()), cell(t.y()), cy, sy, t);
  };
  const YawBins bins(grid.n_yaw, grid.yaw_bin);
  forCompatible(pq, pc, params, [&](const auto& a, const auto& b) {
    double cy, sy;
    pairTurn(a, b, &cy, &sy);
    double yaw = b.angle - a.angle;
    if (yaw > M_PI) yaw -= kTwoPi;
    if (yaw < -M_PI) yaw += kTwoPi;
    int64_t iyaw, turn = -1;
    if (bins.clearOf(yaw, &iyaw))
      turn = bins.halfTurn(iyaw);
    else
      iyaw = bins.exact(std::atan2(sy, cy));
    vote(iyaw, cy, sy, a.mid, b.mid);
    const double turned = yaw < 0.0 ? yaw + M_PI : yaw - M_PI;
    if (turn < 0) turn = bins.of(turned, [&] { return std::atan2(-sy, -cy); });
    vote(turn, -cy, -sy, a.mid, b.mid);
  });
}

}  // namespace

namespace pair_vote_stages {

std::vector<TrunkPair> trunkPairs(const Descriptor& d, double max_len) {
  std::vector<TrunkPair> out;
  const int n = static_cast<int>(d.trunks.size());
  // Most pairs of a submap are far longer than max_len: they are dropped on the squared length
  // (with a margin far above its rounding), before the root and the divisions.
  const double beyond = max_len * (1.0 + 1e-9);
  const double beyond_sq = beyond * beyond;
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      const Eigen::Vector2d a(d.trunks[i].x, d.trunks[i].y), b(d.trunks[j].x, d.trunks[j].y);
      const Eigen::Vector2d e = b - a;
      if (e.squaredNorm() > beyond_sq) continue;  // len > max_len; NaN goes on
      const double len = e.norm();
      if (!(len >= kMinPairM && len <= max_len)) continue;  // also drops non-finite trunks
      out.push_back({len, e.x() / len, e.y() / len, std::atan2(e.y(), e.x()), 0.5 * (a + b), i, j});
    }
  }
  std::sort(out.begin(), out.end(), [](const TrunkPair& x, const TrunkPair& y) {
    return x.len != y.len ? x.len < y.len : (x.i != y.i ? x.i < y.i : x.j < y.j);
  });
  return out;
}

void VoteAccumulator::reserve(size_t n) {
  size_t cap = 16;
  while (cap < 2 * n) cap *= 2;  // at most half full
  slots_.assign(cap, Slot{});
  mask_ = cap - 1;
  bins.clear();
  bins.reserve(n);
}

void VoteAccumulator::rehash(size_t n) {
  size_t cap = 16;
  while (cap < 2 * n) cap *= 2;  // as reserve(n)
  slots_.assign(cap, Slot{});
  mask_ = cap - 1;
  // The bins stay where they are (a reused accumulator keeps their memory); their slots are
  // taken again in bin order, as re-adding them one by one to an empty table would.
  for (size_t i = 0; i < bins.size(); ++i) {
    const int64_t key = packBin(bins[i].iyaw, bins[i].ix, bins[i].iy);
    Slot& s = slots_[slot(key)];
    s.key = key;
    s.index = static_cast<int64_t>(i);
  }
}

size_t VoteAccumulator::slot(int64_t key) const {
  // Fibonacci hashing, then linear probing to the key or the first free slot.
  size_t k =
      static_cast<size_t>((static_cast<uint64_t>(key) * 0x9E3779B97F4A7C15ull) >> 20) & mask_;
  while (slots_[k].key != -1 && slots_[k].key != key) k = (k + 1) & mask_;
  return k;
}

const VoteBin* VoteAccumulator::find(int64_t iyaw, int64_t ix, int64_t iy) const {
  if (slots_.empty()) return nullptr;
  const Slot& s = slots_[slot(packBin(iyaw, ix, iy))];
  return s.index < 0 ? nullptr : &bins[static_cast<size_t>(s.index)];
}

VoteBin& VoteAccumulator::at(int64_t iyaw, int64_t ix, int64_t iy) {
  if (2 * (bins.size() + 1) > slots_.size()) rehash(std::max<size_t>(16, 2 * bins.size()));
  const int64_t key = packBin(iyaw, ix, iy);
  Slot& s = slots_[slot(key)];
  if (s.index < 0) {
    s.key = key;
    s.index = static_cast<int64_t>(bins.size());
    bins.push_back(VoteBin{});
    VoteBin& b = bins.back();
    b.iyaw = iyaw, b.ix = ix, b.iy = iy;
  }
  return bins[static_cast<size_t>(s.index)];
}

VoteAccumulator accumulateVotes(const std::vector<TrunkPair>& pq, const std::vector<TrunkPair>& pc,
                                const MatcherParams& params) {
  VoteAccumulator acc;
  accumulateVotes(pq, pc, params, &acc);
  return acc;
}

void accumulateVotes(const std::vector<TrunkPair>& pq, const std::vector<TrunkPair>& pc,
                     const MatcherParams& params, VoteAccumulator* out) {
  VoteAccumulator& acc = *out;
  const VoteGrid grid = voteGrid(params);
  acc.n_yaw = grid.n_yaw, acc.yaw_bin = grid.yaw_bin, acc.xy_bin = grid.xy_bin;
  // Most votes scatter into bins of their own; the table grows from a guess (a memset of a
  // table sized for every vote would cost more than the votes).
  acc.reserve(std::min<size_t>(2 * countCompatible(pq, pc, params), size_t{1} << 14));
  forEachVote(
      pq, pc, params, grid,
      [&](int64_t iyaw, int64_t ix, int64_t iy, double cy, double sy, const Eigen::Vector2d& t) {
        VoteBin& b = acc.at(iyaw, ix, iy);
        b.count += 1.0, b.cos_sum += cy, b.sin_sum += sy, b.t_sum += t;
      },
      [] {});
}

void VoteCounts::reset(size_t n) {
  size_t cap = 16;
  shift_ = 60;
  // At most a quarter full: a probe past the home slot is a mispredicted branch (half full:
  // votePoses 8 % slower; an eighth: no faster).
  while (cap < 4 * n) cap *= 2, --shift_;
  slots_.assign(cap, 0);
  filter_.assign(cap / 4, 0);
  mask_ = cap - 1;
  votes_.clear();
  votes_.reserve(n);
  multi_.clear();
  yaw_votes_.assign(static_cast<size_t>(n_yaw), 0);
}

void VoteCounts::count() {
  for (const uint64_t bin : votes_) {
    if (bin == kSkipped) continue;
    const size_t f = filterBit(bin);
    filter_[f >> 6] |= uint64_t{1} << (f & 63);
    size_t k = home(bin);
    while (slots_[k] != 0 && slots_[k] >> kCountBits != bin) k = (k + 1) & mask_;
    uint64_t& s = slots_[k];
    s = (s == 0 ? bin << kCountBits : s) + 1;
    if ((s & kCountMask) == 2) multi_.push_back(static_cast<uint32_t>(k));
    ++yaw_votes_[bin >> 32];
  }
}

std::vector<uint64_t> VoteCounts::multiVoteBins() const {
  std::vector<uint64_t> out;
  out.reserve(multi_.size());
  for (uint32_t k : multi_) out.push_back(slots_[k]);
  return out;
}

size_t VoteCounts::bytes() const {
  return (slots_.capacity() + filter_.capacity() + votes_.capacity()) * sizeof(uint64_t) +
         (multi_.capacity() + yaw_votes_.capacity()) * sizeof(uint32_t);
}

bool countVotes(const std::vector<TrunkPair>& pq, const std::vector<TrunkPair>& pc,
                const MatcherParams& params, VoteCounts* out) {
  VoteCounts& counts = *out;
  const VoteGrid grid = voteGrid(params);
  counts.n_yaw = grid.n_yaw, counts.yaw_bin = grid.yaw_bin, counts.xy_bin = grid.xy_bin;
  const size_t n_votes = 2 * countCompatible(pq, pc, params);
  counts.reset(n_votes > VoteCounts::kMaxVotes ? 0 : n_votes);  // no table for refused votes
  if (n_votes > VoteCounts::kMaxVotes) return false;
  forEachVote(
      pq, pc, params, grid,
      [&](int64_t iyaw, int64_t ix, int64_t iy, double, double, const Eigen::Vector2d&) {
        counts.add(compactBin(iyaw, ix, iy));
      },
      [&] { counts.skip(); });
  counts.count();
  return true;
}

namespace {

/// The sums over seed s's 3 x 3 x 3 neighbourhood (yaw wraps around), in one fixed order;
/// find(iyaw, ix, iy) gives a bin's sums, nullptr when it has no vote.
template <class Find>
ScoredSeed neighbourhoodSum(const VoteBin& s, int64_t n_yaw, const Find& find) {
  ScoredSeed sc{&s, VoteBin{}};
  for (int64_t dyaw = -1; dyaw <= 1; ++dyaw) {
    const int64_t iyaw = (s.iyaw + dyaw + n_yaw) % n_yaw;
    for (int64_t dx = -1; dx <= 1; ++dx) {
      for (int64_t dy = -1; dy <= 1; ++dy) {
        const VoteBin* b = find(iyaw, s.ix + dx, s.iy + dy);
        if (!b) continue;
        sc.sum.count += b->count;
        sc.sum.cos_sum += b->cos_sum;
        sc.sum.sin_sum += b->sin_sum;
        sc.sum.t_sum += b->t_sum;
      }
    }
  }
  return sc;
}

/// Strongest neighbourhood first (stable: ties keep the seeds' order).
void sortScored(std::vector<ScoredSeed>* scored) {
  std::stable_sort(scored->begin(), scored->end(), [](const ScoredSeed& x, const ScoredSeed& y) {
    return x.sum.count > y.sum.count;
  });
}

}  // namespace

std::vector<ScoredSeed> scoreSeeds(const VoteAccumulator& acc) {
  std::vector<const VoteBin*> seeds;
  seeds.reserve(acc.bins.size());
  for (const VoteBin& b : acc.bins) seeds.push_back(&b);
  auto fuller = [](const VoteBin* x, const VoteBin* y) {
    if (x->count != y->count) return x->count > y->count;
    if (x->iyaw != y->iyaw) return x->iyaw < y->iyaw;
    return x->ix != y->ix ? x->ix < y->ix : x->iy < y->iy;
  };
  const size_t n_seeds = std::min(kSeedBins, seeds.size());
  std::partial_sort(seeds.begin(), seeds.begin() + n_seeds, seeds.end(), fuller);
  seeds.resize(n_seeds);

  std::vector<ScoredSeed> scored;
  for (const VoteBin* s : seeds)
    scored.push_back(neighbourhoodSum(*s, acc.n_yaw, [&](int64_t iyaw, int64_t ix, int64_t iy) {
      return acc.find(iyaw, ix, iy);
    }));
  sortScored(&scored);
  return scored;
}

namespace {

/// The bins of one vote with the n smallest bins (as by iyaw, ix, iy), ascending. Those of
/// the lowest yaw bins: cut where the votes up to a yaw bin, less all votes of the bins of more
/// (multi_votes), reach n; only the votes below the cut are looked at.
std::vector<uint64_t> smallestSingleVoteBins(const VoteCounts& counts, size_t multi_votes,
                                             size_t n) {
  if (n == 0) return {};
  const std::vector<uint32_t>& per_yaw = counts.yawVotes();
  uint64_t cut = per_yaw.size();  // yaw bins below it
  for (size_t iyaw = 0, votes = 0; iyaw < per_yaw.size(); ++iyaw) {
    votes += per_yaw[iyaw];
    if (votes >= n + multi_votes) {
      cut = iyaw + 1;
      break;
    }
  }
  std::vector<uint64_t> out;
  for (uint64_t bin : counts.votes())
    if (bin >> 32 < cut && counts.votesIn(bin) == 1) out.push_back(bin);
  n = std::min(n, out.size());
  std::nth_element(out.begin(), out.begin() + n, out.end());
  out.resize(n);
  std::sort(out.begin(), out.end());
  return out;
}

/// The seeds of scoreSeeds: the kSeedBins bins of most votes, ties by bin (as by iyaw, ix,
/// iy), fullest first.
std::vector<VoteBin> seedBins(const VoteCounts& counts) {
  constexpr uint64_t kCount = VoteCounts::kCountMask;
  std::vector<uint64_t> multi = counts.multiVoteBins();  // bin << kCountBits | count
  const size_t n_multi = std::min(kSeedBins, multi.size());
  std::partial_sort(multi.begin(), multi.begin() + n_multi, multi.end(),
                    [](uint64_t x, uint64_t y) {
                      return (x & kCount) != (y & kCount) ? (x & kCount) > (y & kCount) : x < y;
                    });
  size_t multi_votes = 0;
  for (uint64_t s : multi) multi_votes += s & kCount;
  multi.resize(n_multi);
  const std::vector<uint64_t> single =
      smallestSingleVoteBins(counts, multi_votes, kSeedBins - n_multi);
  std::vector<VoteBin> seeds(n_multi + single.size());
  for (size_t i = 0; i < seeds.size(); ++i) {
    const bool up = i < n_multi;
    unpackCompactBin(up ? multi[i] >> VoteCounts::kCountBits : single[i - n_multi], &seeds[i]);
    seeds[i].count = static_cast<double>(up ? multi[i] & kCount : 1);
  }
  return seeds;
}

/// The sums of a few bins (the seeds' neighbourhoods): an open-addressing table small enough
/// for L1, behind a bitmap (64 bits per bin) that turns most other bins away with one test.
class BinSums {
 public:
  /// For the distinct bins `bins`, their sums zero.
  explicit BinSums(const std::vector<uint64_t>& bins) {
    size_t cap = 16;
    while (cap < 2 * bins.size()) cap *= 2;
    bins_.assign(cap, 0);
    index_.resize(cap);
    mask_ = cap - 1;
    filter_.assign(cap / 2, 0);
    sums_.resize(bins.size());
    for (size_t i = 0; i < bins.size(); ++i) {
      const uint64_t h = hash(bins[i]);
      size_t k = h & mask_;
      while (bins_[k] != 0) k = (k + 1) & mask_;
      bins_[k] = bins[i];
      index_[k] = static_cast<uint32_t>(i);
      filter_[(h >> 6) & (filter_.size() - 1)] |= uint64_t{1} << (h & 63);
    }
  }
  /// bin's sums, nullptr when it is not one of them.
  VoteBin* find(uint64_t bin) {
    const uint64_t h = hash(bin);
    if (!(filter_[(h >> 6) & (filter_.size() - 1)] >> (h & 63) & 1)) return nullptr;
    for (size_t k = h & mask_; bins_[k] != 0; k = (k + 1) & mask_)
      if (bins_[k] == bin) return &sums_[index_[k]];
    return nullptr;
  }

 private:
  static uint64_t hash(uint64_t bin) { return (bin * 0x9E3779B97F4A7C15ull) >> 32; }
  std::vector<uint64_t> bins_;  ///< 0: free
  std::vector<uint32_t> index_;
  std::vector<VoteBin> sums_;
  std::vector<uint64_t> filter_;
  size_t mask_;
};

/// The bins with votes around the seeds, each once.
std::vector<uint64_t> votedAround(const VoteCounts& counts, const std::vector<VoteBin>& seeds) {
  std::vector<uint64_t> voted;
  for (const VoteBin& s : seeds) {
    for (int64_t dyaw = -1; dyaw <= 1; ++dyaw) {
      const int64_t iyaw = (s.iyaw + dyaw + counts.n_yaw) % counts.n_yaw;
      for (int64_t dx = -1; dx <= 1; ++dx) {
        for (int64_t dy = -1; dy <= 1; ++dy) {
          const uint64_t bin = compactBin(iyaw, s.ix + dx, s.iy + dy);
          if (counts.votesIn(bin) > 0) voted.push_back(bin);
        }
      }
    }
  }
  std::sort(voted.begin(), voted.end());
  voted.erase(std::unique(voted.begin(), voted.end()), voted.end());
  return voted;
}

/// The votes of the bins in *sums, summed in vote order (as accumulateVotes sums them): the
/// pairs' votes cast again, only where the bin counted for the vote is one of them.
void sumVotes(const VoteCounts& counts, const std::vector<TrunkPair>& pq,
              const std::vector<TrunkPair>& pc, const MatcherParams& params, BinSums* sums) {
  const std::vector<uint64_t>& votes = counts.votes();
  size_t v = 0;
  auto add = [&](VoteBin* b, double cy, double sy, const Eigen::Vector2d& mq,
                 const Eigen::Vector2d& mc) {
    b->count += 1.0, b->cos_sum += cy, b->sin_sum += sy, b->t_sum += proposalT(cy, sy, mq, mc);
  };
  forCompatible(pq, pc, params, [&](const TrunkPair& a, const TrunkPair& b) {
    VoteBin* first = sums->find(votes[v]);
    VoteBin* second = sums->find(votes[v + 1]);
    v += 2;
    if (!first && !second) return;
    double cy, sy;
    pairTurn(a, b, &cy, &sy);
    if (first) add(first, cy, sy, a.mid, b.mid);
    if (second) add(second, -cy, -sy, a.mid, b.mid);
  });
}

}  // namespace

std::vector<ScoredSeed> scoreSeeds(const VoteCounts& counts, const std::vector<TrunkPair>& pq,
                                   const std::vector<TrunkPair>& pc, const MatcherParams& params,
                                   std::vector<VoteBin>* seeds) {
  *seeds = seedBins(counts);
  BinSums sums(votedAround(counts, *seeds));
  sumVotes(counts, pq, pc, params, &sums);
  std::vector<ScoredSeed> scored;
  for (const VoteBin& s : *seeds)
    scored.push_back(neighbourhoodSum(s, counts.n_yaw, [&](int64_t iyaw, int64_t ix, int64_t iy) {
      return sums.find(compactBin(iyaw, ix, iy));
    }));
  sortScored(&scored);
  return scored;
}

std::vector<VotePeak> selectPeaks(const std::vector<ScoredSeed>& scored, int64_t n_yaw,
                                  int max_peaks) {
  std::vector<VotePeak> peaks;
  std::vector<const VoteBin*> taken;
  for (const ScoredSeed& sc : scored) {
    bool near = false;
    for (const VoteBin* t : taken) {
      int64_t dyaw = std::abs(sc.seed->iyaw - t->iyaw);
      dyaw = std::min(dyaw, n_yaw - dyaw);
      if (dyaw <= 1 && std::abs(sc.seed->ix - t->ix) <= 1 && std::abs(sc.seed->iy - t->iy) <= 1) {
        near = true;
        break;
      }
    }
    if (near) continue;
    if (sc.sum.count < kMinPeakVotes) break;
    taken.push_back(sc.seed);
    VotePeak p;
    p.yaw = std::atan2(sc.sum.sin_sum, sc.sum.cos_sum);
    p.t = sc.sum.t_sum / sc.sum.count;
    p.votes = sc.sum.count;
    peaks.push_back(p);
    if (static_cast<int>(peaks.size()) >= max_peaks) break;
  }
  return peaks;
}

}  // namespace pair_vote_stages

namespace {

/// Whether two doubles have the same bits.
bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

/// trunkPairs(q, max_len), kept per thread: a loop query votes its descriptor against a dozen
/// candidates in a row. Keyed by max_len and the trunks' coordinates, bit for bit, never by
/// address (another descriptor may come to live there).
const std::vector<pair_vote_stages::TrunkPair>& queryPairs(const Descriptor& q, double max_len) {
  thread_local std::vector<double> key{std::numeric_limits<double>::quiet_NaN()};
  thread_local std::vector<pair_vote_stages::TrunkPair> pairs;
  bool same = key.size() == 1 + 2 * q.trunks.size() && sameBits(key[0], max_len);
  for (size_t i = 0; same && i < q.trunks.size(); ++i)
    same = sameBits(key[1 + 2 * i], q.trunks[i].x) && sameBits(key[2 + 2 * i], q.trunks[i].y);
  if (same) return pairs;
  key.assign(1, max_len);
  for (const TrunkLandmark& t : q.trunks) key.push_back(t.x), key.push_back(t.y);
  pairs = pair_vote_stages::trunkPairs(q, max_len);
  return pairs;
}

/// votePoses on the full accumulator, for pairs that cast too many votes to count.
std::vector<VotePeak> accumulatedPeaks(const std::vector<pair_vote_stages::TrunkPair>& pq,
                                       const std::vector<pair_vote_stages::TrunkPair>& pc,
                                       const MatcherParams& params, int max_peaks) {
  const pair_vote_stages::VoteAccumulator acc = pair_vote_stages::accumulateVotes(pq, pc, params);
  return pair_vote_stages::selectPeaks(pair_vote_stages::scoreSeeds(acc), acc.n_yaw, max_peaks);
}

}  // namespace

std::vector<VotePeak> votePoses(const Descriptor& q, const Descriptor& c,
                                const MatcherParams& params, int max_peaks) {
  using pair_vote_stages::TrunkPair;
  if (q.trunks.size() < 2 || c.trunks.size() < 2 || max_peaks <= 0) return {};
  const std::vector<TrunkPair>& pq = queryPairs(q, params.vote_max_pair_m);
  const std::vector<TrunkPair> pc = pair_vote_stages::trunkPairs(c, params.vote_max_pair_m);
  if (pq.empty() || pc.empty()) return {};
  // One table per thread, its memory kept between calls (see accumulateVotes).
  thread_local pair_vote_stages::VoteCounts counts;
  if (!pair_vote_stages::countVotes(pq, pc, params, &counts))
    return accumulatedPeaks(pq, pc, params, max_peaks);
  std::vector<pair_vote_stages::VoteBin> seeds;
  std::vector<VotePeak> peaks = pair_vote_stages::selectPeaks(
      pair_vote_stages::scoreSeeds(counts, pq, pc, params, &seeds), counts.n_yaw, max_peaks);
  // Submap pairs cast ~10^3-10^5 votes; an outsized pair's table is not held on to.
  constexpr size_t kKeptBytes = size_t{8} << 20;
  if (counts.bytes() > kKeptBytes) counts = pair_vote_stages::VoteCounts{};
  return peaks;
}

}  // namespace dtif
