// Hierarchical vertex correspondence construction, paper Algorithm 1.
#include "dtif/core/matching/matcher.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "dtif/core/matching/matcher_stages.h"

namespace dtif {
namespace {

/// Cons_l / Cons_r of Eq. (3.4): relative tolerance, plus an absolute one so that short edges and
/// thin stems are not held to a tolerance below the measurement noise.
inline bool consistent(float a, float b, double rel, double abs_tol) {
  const double diff = std::fabs(static_cast<double>(a) - b);
  return diff <= abs_tol || diff <= rel * std::max(a, b);
}

/// consistentEdges(q, c, params) == 7 with an early exit at the first inconsistent edge or
/// radius: the only question for a pair that cannot give weak support.
inline bool fullyConsistent(const Triangle& q, const Triangle& c, const MatcherParams& params) {
  for (int a = 0; a < 3; ++a) {
    if (!consistent(q.len[a], c.len[a], params.edge_rel_tol, params.edge_abs_tol_m)) return false;
  }
  for (int b = 0; b < 3; ++b) {
    if (!consistent(q.r[b], c.r[b], params.radius_rel_tol, params.radius_abs_tol_m)) return false;
  }
  return true;
}

/// consistentEdges, each radius compared once (every vertex ends two edges); inlined into the
/// triangle-pair loop, where it runs for every pair of Delaunay faces.
inline int edgeMask(const Triangle& q, const Triangle& c, const MatcherParams& params) {
  const double el = params.edge_rel_tol, ea = params.edge_abs_tol_m;
  const double rl = params.radius_rel_tol, ra = params.radius_abs_tol_m;
  const int r0 = consistent(q.r[0], c.r[0], rl, ra), r1 = consistent(q.r[1], c.r[1], rl, ra),
            r2 = consistent(q.r[2], c.r[2], rl, ra);
  // kEdgeEnds: e1 joins vertices 0 and 2, e2 0 and 1, e3 1 and 2.
  static_assert(kEdgeEnds[0][0] == 0 && kEdgeEnds[0][1] == 2 && kEdgeEnds[1][0] == 0 &&
                kEdgeEnds[1][1] == 1 && kEdgeEnds[2][0] == 1 && kEdgeEnds[2][1] == 2);
  return (consistent(q.len[0], c.len[0], el, ea) & r0 & r2) |
         ((consistent(q.len[1], c.len[1], el, ea) & r0 & r1) << 1) |
         ((consistent(q.len[2], c.len[2], el, ea) & r1 & r2) << 2);
}

/// Floats as integers of the same order (negative ones reversed), for searching float bounds.
int64_t floatKey(float f) {
  int32_t i = 0;
  std::memcpy(&i, &f, sizeof i);
  return i >= 0 ? int64_t{i} : -int64_t{i & 0x7fffffff};
}
float keyFloat(int64_t k) {
  const uint32_t u = k >= 0 ? static_cast<uint32_t>(k) : (static_cast<uint32_t>(-k) | 0x80000000u);
  float f = 0.0f;
  std::memcpy(&f, &u, sizeof f);
  return f;
}

/// The last key from `from` towards `to` (inclusive) where pass holds, given that it holds at
/// `from` and, once it fails, fails all the way on: galloping from the guess, then bisection.
template <class Pass>
int64_t lastPassing(int64_t from, int64_t to, int64_t guess, const Pass& pass) {
  const int64_t dir = to >= from ? 1 : -1;
  auto clampKey = [&](int64_t k) {
    return dir > 0 ? std::clamp(k, from, to) : std::clamp(k, to, from);
  };
  int64_t good = from, bad = to + dir;  // pass(good) holds; bad fails (to + dir: none yet)
  guess = clampKey(guess);
  if (pass(keyFloat(guess))) {
    good = guess;
  } else {
    bad = guess;
  }
  if (bad == to + dir) {  // outwards from good
    for (int64_t step = 1; good != to; step *= 2) {
      const int64_t k = clampKey(good + dir * step);
      if (!pass(keyFloat(k))) {
        bad = k;
        break;
      }
      good = k;
    }
    if (good == to) return to;
  } else {  // inwards from bad
    for (int64_t step = 1;; step *= 2) {
      const int64_t k = clampKey(bad - dir * step);
      if ((k - good) * dir <= 0) break;
      if (pass(keyFloat(k))) {
        good = k;
        break;
      }
      bad = k;
    }
  }
  while ((bad - good) * dir > 1) {
    const int64_t mid = good + (bad - good) / 2;
    if (pass(keyFloat(mid))) {
      good = mid;
    } else {
      bad = mid;
    }
  }
  return good;
}

/// The finite floats b with consistent(a, b, rel, abs_tol): an interval around a (on either
/// side the gap grows faster than the tolerance), found by searching `consistent` itself, so
/// that the interval decides every finite b exactly as it. False for a negative or non-finite a.
bool consistentRange(float a, double rel, double abs_tol, float* lo, float* hi) {
  if (!(a >= 0.0f && std::isfinite(a))) return false;
  auto pass = [&](float b) { return consistent(a, b, rel, abs_tol); };
  constexpr float kMax = std::numeric_limits<float>::max();
  const int64_t ka = floatKey(a), kmax = floatKey(kMax);
  const double up = rel < 1.0 ? std::max(a + abs_tol, a / (1.0 - rel)) : kMax;
  const double down = std::min(a - abs_tol, a * (1.0 - rel));
  *hi = keyFloat(
      lastPassing(ka, kmax, floatKey(static_cast<float>(std::min<double>(up, kMax))), pass));
  *lo = keyFloat(
      lastPassing(ka, -kmax, floatKey(static_cast<float>(std::max<double>(down, -kMax))), pass));
  return true;
}

}  // namespace

std::vector<ConsistencyBounds> consistencyBounds(const std::vector<MatchTriangle>& t,
                                                 const MatcherParams& params) {
  std::vector<ConsistencyBounds> out(t.size());
  for (size_t i = 0; i < t.size(); ++i) {
    ConsistencyBounds& b = out[i];
    for (int a = 0; a < 3; ++a) {
      b.exact = b.exact && consistentRange(t[i].t.len[a], params.edge_rel_tol,
                                           params.edge_abs_tol_m, &b.lo[a], &b.hi[a]);
      b.exact = b.exact && consistentRange(t[i].t.r[a], params.radius_rel_tol,
                                           params.radius_abs_tol_m, &b.lo[3 + a], &b.hi[3 + a]);
    }
  }
  return out;
}

namespace {

/// Trunk i's candidates for its kk nearest: every other finite trunk whose squared horizontal
/// distance is within a hair of the kk-th smallest (the hair covers the rounding of hypot), as
/// (squared distance, index) in `near`. A sweep outwards over the trunks sorted by x (`by_x`, i at
/// position pos) stops on a side once the x gap alone exceeds the bound: the trunks beyond have kk
/// others clearly nearer. The same set as a scan of all n trunks, in O(n log n) per descriptor
/// for a stand rather than O(n^2).
void nearestCandidates(const Trunks& tr, const std::vector<int>& by_x, int pos, int kk,
                       std::vector<std::pair<double, int>>* near, std::vector<double>* heap) {
  const TrunkLandmark& a = tr[static_cast<size_t>(by_x[static_cast<size_t>(pos)])];
  near->clear();
  heap->clear();  // max-heap of the kk smallest squared distances so far
  const auto bound = [&] {
    return static_cast<int>(heap->size()) < kk ? std::numeric_limits<double>::infinity()
                                               : heap->front() * (1.0 + 1e-9);
  };
  const auto visit = [&](int j) {
    const double dx = a.x - tr[static_cast<size_t>(j)].x, dy = a.y - tr[static_cast<size_t>(j)].y;
    const double d2 = dx * dx + dy * dy;
    near->emplace_back(d2, j);
    if (static_cast<int>(heap->size()) < kk) {
      heap->push_back(d2);
      std::push_heap(heap->begin(), heap->end());
    } else if (d2 < heap->front()) {
      std::pop_heap(heap->begin(), heap->end());
      heap->back() = d2;
      std::push_heap(heap->begin(), heap->end());
    }
  };
  const int n = static_cast<int>(by_x.size());
  const auto gap2 = [&](int p) {
    const double dx = a.x - tr[static_cast<size_t>(by_x[static_cast<size_t>(p)])].x;
    return dx * dx;
  };
  // The nearer side in x first, so that the bound tightens early.
  int l = pos - 1, r = pos + 1;
  while (true) {
    const bool left_ok = l >= 0 && gap2(l) <= bound();
    const bool right_ok = r < n && gap2(r) <= bound();
    if (!left_ok && !right_ok) break;
    if (left_ok && (!right_ok || gap2(l) <= gap2(r))) {
      visit(by_x[static_cast<size_t>(l--)]);
    } else {
      visit(by_x[static_cast<size_t>(r++)]);
    }
  }
  const double b = bound();
  near->erase(std::remove_if(near->begin(), near->end(),
                             [b](const std::pair<double, int>& e) { return e.first > b; }),
              near->end());
}

/// A triangle's trunk indices, sorted, packed into one integer (21 bits each) whose order is
/// that of the sorted index triples: sorting and searching integers instead of arrays.
constexpr int kKeyBits = 21;
constexpr int kMaxKeyTrunks = 1 << kKeyBits;

uint64_t sortedKey(int a, int b, int c) {
  if (a > b) std::swap(a, b);
  if (b > c) std::swap(b, c);
  if (a > b) std::swap(a, b);
  const uint64_t mask = kMaxKeyTrunks - 1;
  return ((static_cast<uint64_t>(a) & mask) << (2 * kKeyBits)) |
         ((static_cast<uint64_t>(b) & mask) << kKeyBits) | (static_cast<uint64_t>(c) & mask);
}

int keyTrunk(uint64_t key, int slot) {
  return static_cast<int>((key >> ((2 - slot) * kKeyBits)) & (kMaxKeyTrunks - 1));
}

// Scratch reused between matchTriangles calls: a database load computes them for every entry.
struct TriangleScratch {
  std::vector<uint64_t> keys;
  std::vector<int> by_x;
  std::vector<std::pair<double, int>> near;
  std::vector<double> heap;
  std::vector<std::pair<float, uint32_t>> order;
  std::vector<MatchTriangle> kept;
};

// The Delaunay faces alone, sorted by longest edge like the general case (matching searches
// them by it).
std::vector<MatchTriangle> facesOnly(const Descriptor& d) {
  std::vector<MatchTriangle> out;
  for (const Triangle& t : d.triangles) out.push_back({t, true});
  std::stable_sort(out.begin(), out.end(), [](const MatchTriangle& a, const MatchTriangle& b) {
    return a.t.len[0] < b.t.len[0];
  });
  return out;
}

// Into s->keys, every triangle's key shifted left by one, its low bit set for a Delaunay face
// (after sorting, a triangle's copies are adjacent and the face copy, if any, comes last): the
// faces, then each trunk with every two of its kk nearest neighbours.
void triangleKeys(const Descriptor& d, int kk, TriangleScratch* s) {
  s->keys.clear();
  for (const Triangle& t : d.triangles) {
    s->keys.push_back(sortedKey(t.v[0], t.v[1], t.v[2]) << 1 | 1);
  }
  // Trunks with a non-finite centre (never in a validated descriptor) take no part in the
  // neighbour triangles.
  std::vector<int>& by_x = s->by_x;
  by_x.clear();
  for (int i = 0; i < static_cast<int>(d.trunks.size()); ++i) {
    if (std::isfinite(d.trunks[static_cast<size_t>(i)].x) &&
        std::isfinite(d.trunks[static_cast<size_t>(i)].y))
      by_x.push_back(i);
  }
  std::sort(by_x.begin(), by_x.end(), [&](int a, int b) {
    return d.trunks[static_cast<size_t>(a)].x < d.trunks[static_cast<size_t>(b)].x;
  });
  const int m = std::min(kk, static_cast<int>(by_x.size()) - 1);
  std::vector<std::pair<double, int>>& near = s->near;
  for (int pos = 0; m >= 2 && pos < static_cast<int>(by_x.size()); ++pos) {
    const int i = by_x[static_cast<size_t>(pos)];
    nearestCandidates(d.trunks, by_x, pos, m, &near, &s->heap);
    // The m nearest by (hypot, index), hypot only for the candidates, and only when there are
    // more than m (near-ties at the bound): the pairs below do not depend on the order.
    if (static_cast<int>(near.size()) > m) {
      for (auto& e : near) {
        const TrunkLandmark &a = d.trunks[static_cast<size_t>(i)],
                            &c = d.trunks[static_cast<size_t>(e.second)];
        e.first = std::hypot(a.x - c.x, a.y - c.y);
      }
      std::partial_sort(near.begin(), near.begin() + m, near.end());
    }
    for (int a = 0; a < m; ++a)
      for (int b = a + 1; b < m; ++b)
        s->keys.push_back(sortedKey(i, near[a].second, near[b].second) << 1);
  }
}

// The distinct triangles of the sorted keys as canonical triangles, without degenerate ones and
// (unless a face) thin slivers, by longest edge, ties in key order.
std::vector<MatchTriangle> keptTriangles(const Descriptor& d, TriangleScratch* s) {
  const std::vector<uint64_t>& keys = s->keys;
  s->kept.clear();
  s->order.clear();
  for (size_t j = 0; j < keys.size(); ++j) {
    const uint64_t t = keys[j] >> 1;
    if (j + 1 < keys.size() && keys[j + 1] >> 1 == t) continue;  // the last copy: the face
    const bool face = keys[j] & 1;
    const Triangle tri =
        makeCanonicalTriangle(d.trunks, keyTrunk(t, 0), keyTrunk(t, 1), keyTrunk(t, 2));
    if (tri.len[2] <= 1e-3) continue;  // collinear or duplicate trunks
    // Thin slivers: their shortest edge tells nothing reliable about the correspondence.
    const double sp = 0.5 * (tri.len[0] + tri.len[1] + tri.len[2]);
    const double area2 = sp * (sp - tri.len[0]) * (sp - tri.len[1]) * (sp - tri.len[2]);
    if (!face && (area2 <= 0.0 || std::sqrt(area2) < 0.05 * tri.len[0] * tri.len[0])) continue;
    s->order.emplace_back(tri.len[0], static_cast<uint32_t>(s->kept.size()));
    s->kept.push_back({tri, face});
  }
  // A stable sort of kept by longest edge, without moving triangles.
  std::sort(s->order.begin(), s->order.end());
  std::vector<MatchTriangle> out;
  out.reserve(s->kept.size());
  for (const auto& o : s->order) out.push_back(s->kept[o.second]);
  return out;
}

}  // namespace

/// Computed from the trunks on both sides, so nothing extra crosses the radio link.
std::vector<MatchTriangle> matchTriangles(const Descriptor& d, int k) {
  // (More trunks than a key holds: far beyond kMaxDescriptorTrunks, never a valid descriptor.)
  if (k <= 0 || d.trunks.size() < 3 || d.trunks.size() >= static_cast<size_t>(kMaxKeyTrunks)) {
    return facesOnly(d);
  }
  thread_local TriangleScratch scratch;  // one TLS lookup per call, not one per use
  triangleKeys(d, std::min(k, static_cast<int>(d.trunks.size()) - 1), &scratch);
  std::sort(scratch.keys.begin(), scratch.keys.end());
  return keptTriangles(d, &scratch);
}

std::string MatcherParams::validate() const {
  std::ostringstream err;
  auto unit = [&](const char* n, double v) {
    if (!(v >= 0.0 && v <= 1.0)) err << n << " must be in [0, 1]; ";
  };
  unit("min_edge_hist_sim", min_edge_hist_sim);
  unit("min_radius_hist_sim", min_radius_hist_sim);
  if (!(edge_rel_tol >= 0.0 && edge_rel_tol < 1.0)) err << "edge_rel_tol must be in [0, 1); ";
  if (!(edge_abs_tol_m >= 0.0 && std::isfinite(edge_abs_tol_m))) {
    err << "edge_abs_tol_m must be >= 0; ";
  }
  if (!(radius_rel_tol >= 0.0 && radius_rel_tol <= 1.0))
    err << "radius_rel_tol must be in [0, 1]; ";
  if (!(radius_abs_tol_m >= 0.0 && std::isfinite(radius_abs_tol_m))) {
    err << "radius_abs_tol_m must be >= 0; ";
  }
  if (weak_support_min < 0) err << "weak_support_min must be >= 0; ";
  if (!(alpha_w >= 0.0 && std::isfinite(alpha_s))) err << "alpha_s, alpha_w must be >= 0; ";
  if (!(alpha_s > alpha_w)) err << "alpha_s must exceed alpha_w (Eq. 3.9); ";
  if (max_correspondences < 2) err << "max_correspondences must be >= 2; ";
  if (neighbour_triangles < 0 || neighbour_triangles > 12) {
    err << "neighbour_triangles must be in [0, 12]; ";
  }
  if (vote_max_correspondences < 0) err << "vote_max_correspondences must be >= 0 (0: no limit); ";
  if (!(vote_max_pair_m >= 2.0 && vote_max_pair_m <= 100.0)) {
    err << "vote_max_pair_m must be in [2, 100]; ";
  }
  if (!(vote_yaw_bin_deg >= 0.1 && vote_yaw_bin_deg <= 30.0)) {
    err << "vote_yaw_bin_deg must be in [0.1, 30]; ";
  }
  if (!(vote_xy_bin_m >= 0.05 && vote_xy_bin_m <= 10.0)) {
    err << "vote_xy_bin_m must be in [0.05, 10]; ";
  }
  return err.str();
}

double histogramIntersection(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size() || a.empty()) return 0.0;  // different binning: not comparable
  double s = 0.0;
  for (size_t i = 0; i < a.size(); ++i) s += std::min(a[i], b[i]);
  return s;
}

std::vector<Correspondence> buildCorrespondences(const Descriptor& query,
                                                 const Descriptor& candidate,
                                                 const MatcherParams& params, MatchStats* stats) {
  return buildCorrespondences(query, candidate, params, stats, nullptr, nullptr);
}

namespace matcher_stages {

bool passesScreening(const Descriptor& query, const Descriptor& candidate,
                     const MatcherParams& params, MatchStats* stats) {
  stats->edge_hist_sim = histogramIntersection(query.edge_hist, candidate.edge_hist);
  stats->radius_hist_sim = histogramIntersection(query.radius_hist, candidate.radius_hist);
  if (stats->edge_hist_sim < params.min_edge_hist_sim ||
      stats->radius_hist_sim < params.min_radius_hist_sim) {
    stats->screened_out = true;
    return false;
  }
  return true;
}

int consistentEdges(const Triangle& q, const Triangle& c, const MatcherParams& params) {
  return edgeMask(q, c, params);
}

namespace {

/// The candidate triangles' values as columns, so that a query triangle's test against a run
/// of them is a loop over contiguous floats that the compiler vectorises; `face` is 7 for a
/// Delaunay face, 0 for a neighbour triangle.
struct TriangleColumns {
  std::array<std::vector<float>, 6> v;  // len[0..2], r[0..2]
  std::vector<uint8_t> face;
  void assign(const std::vector<MatchTriangle>& t) {
    for (int a = 0; a < 6; ++a) v[a].resize(t.size());
    face.resize(t.size());
    for (size_t j = 0; j < t.size(); ++j) {
      for (int a = 0; a < 3; ++a) {
        v[a][j] = t[j].t.len[a];
        v[3 + a][j] = t[j].t.r[a];
      }
      face[j] = t[j].delaunay ? 7 : 0;
    }
  }
};

/// mask[j - from] = the mask of query triangle b against candidate triangle j, for j in
/// [from, to) as edgeMask would give it for a pair of faces (q_face and c_j a face), else 7
/// when fully consistent and 0 otherwise: from b's intervals, without branches. The partial
/// mask is 7 exactly when every value is in its interval (each edge needs its length and both
/// end radii), so the non-face case is "partial mask == 7". Comparisons only, so the AVX2
/// clone (32 pairs a step where the CPU has AVX2) gives the same masks.
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("avx2", "default")))
#endif
void boundsMasks(const TriangleColumns& c, const ConsistencyBounds& b, bool q_face, size_t from,
                 size_t to, std::vector<uint8_t>* mask) {
  const size_t n = to - from;
  mask->resize(n);
  uint8_t* m = mask->data();
  const float* x[6];
  for (int a = 0; a < 6; ++a) x[a] = c.v[a].data() + from;
  const uint8_t* face = c.face.data() + from;
  const uint8_t q7 = q_face ? 7 : 0;
  for (size_t j = 0; j < n; ++j) {
    uint8_t in[6];
    for (int a = 0; a < 6; ++a)
      in[a] = static_cast<uint8_t>(static_cast<int>(x[a][j] >= b.lo[a]) & (x[a][j] <= b.hi[a]));
    const uint8_t partial = static_cast<uint8_t>(
        (in[0] & in[3] & in[5]) | ((in[1] & in[3] & in[4]) << 1) | ((in[2] & in[4] & in[5]) << 2));
    const uint8_t full = static_cast<uint8_t>(-static_cast<uint8_t>(partial == 7));  // 0 or 0xff
    m[j] = static_cast<uint8_t>(partial & ((q7 & face[j]) | full));
  }
}

/// The scratch of accumulateSupport, one per thread. Out of line: a thread_local of a shared
/// library is reached through __tls_get_addr, which the compiler re-called inside the
/// triangle-pair loop when the scratch was used there directly.
struct SupportScratch {
  TriangleColumns cols;
  std::vector<uint8_t> mask;
  /// E^s | E^w << 16 per vertex pair while counting (one load and store per count, not two
  /// loads of separate arrays); all zero between calls.
  std::vector<uint32_t> packed;
};
__attribute__((noinline)) SupportScratch& supportScratch() {
  thread_local SupportScratch scratch;
  return scratch;
}

/// The vertex support being counted, in the scratch's packed table; out() copies it into
/// sup. The table is all zero again afterwards: out() clears it, the destructor when out() was
/// not reached (an allocation failing). The non-zero entries are found by a scan of the table
/// in out(), not listed at their first touch: that test was a branch per count that the
/// lattice stands' counts mispredicted (a first touch is a coin toss there).
class SupportCounts {
 public:
  /// `saturating`: whether a count could reach 65535 (else plain adds give the same values).
  SupportCounts(std::vector<uint32_t>* table, VertexSupport* sup, bool saturating)
      : sup_(*sup), nc_(sup_.nc), n_(sup_.nq * sup_.nc), saturating_(saturating) {
    if (table->size() < n_) table->resize(n_, 0);
    packed_ = table->data();
  }
  ~SupportCounts() {
    if (!done_) std::fill(packed_, packed_ + n_, 0u);
  }
  /// Eq. (3.4)-(3.7) for one triangle pair of mask m (7: all edges consistent): strong
  /// support to its three vertex pairs, else weak support to the ends of its consistent edges.
  /// Masks other than 0 and 7 come from pairs of Delaunay faces only: neighbour triangles share
  /// their edges many times over, and their partial matches would pile up weak support.
  /// Every vertex pair gets its increment of the mask (kIncrements) at once, without a branch
  /// per mask or edge: which edges agree follows no pattern.
  void add(const Triangle& q, const Triangle& c, int m) {
    if (saturating_) {
      addAt<true>(rowsOf(q), c, m);
    } else {
      addAt<false>(rowsOf(q), c, m);
    }
  }
  /// The table rows of q's vertices (q.v[j] * nc), for addAt: once per query triangle, not
  /// per pair of its window.
  struct Rows {
    std::array<size_t, 3> r;
  };
  Rows rowsOf(const Triangle& q) const {
    return {{static_cast<size_t>(q.v[0]) * nc_, static_cast<size_t>(q.v[1]) * nc_,
             static_cast<size_t>(q.v[2]) * nc_}};
  }
  /// add() of the query triangle of `rows`, for a table that saturates (kSaturating) or not.
  template <bool kSaturating>
  void addAt(const Rows& rows, const Triangle& c, int m) {
    const std::array<uint32_t, 3>& inc = kIncrements[m];
    for (int j = 0; j < 3; ++j) bump<kSaturating>(rows.r[j] + c.v[j], inc[j]);
  }
  bool saturating() const { return saturating_; }
  /// The counts into sup (touched: the non-zero entries by index), without branches.
  void out() {
    sup_.strong.resize(n_);
    sup_.weak.resize(n_);
    sup_.touched.resize(n_);
    size_t m = 0;
    for (size_t k = 0; k < n_; ++k) {
      const uint32_t v = packed_[k];
      sup_.strong[k] = static_cast<uint16_t>(v & 0xffffu);
      sup_.weak[k] = static_cast<uint16_t>(v >> 16);
      sup_.touched[m] = static_cast<uint32_t>(k);
      m += v != 0;
    }
    sup_.touched.resize(m);
    std::fill(packed_, packed_ + n_, 0u);
    done_ = true;
  }

 private:
  /// Per mask, the packed increment (strong | weak << 16) of each vertex pair: Eq. (3.6) for
  /// mask 7, else Eq. (3.7), one weak count per consistent edge the vertex ends.
  static constexpr std::array<std::array<uint32_t, 3>, 8> kIncrements = [] {
    std::array<std::array<uint32_t, 3>, 8> t{};
    for (int m = 1; m < 8; ++m) {
      for (int a = 0; a < 3; ++a) {
        if (m == 7) t[m][a] = 1;
        if (m == 7 || !(m & (1 << a))) continue;
        t[m][kEdgeEnds[a][0]] += 1u << 16, t[m][kEdgeEnds[a][1]] += 1u << 16;
      }
    }
    return t;
  }();
  /// Both counts of entry k raised by inc, each saturating at 65535 (as one count at a time).
  template <bool kSaturating>
  void bump(size_t k, uint32_t inc) {
    if (!kSaturating) {
      packed_[k] += inc;
      return;
    }
    const uint32_t v = packed_[k];
    const uint32_t s = std::min((v & 0xffffu) + (inc & 0xffffu), 0xffffu);
    const uint32_t w = std::min((v >> 16) + (inc >> 16), 0xffffu);
    packed_[k] = s | w << 16;
  }
  VertexSupport& sup_;
  size_t nc_, n_;
  bool saturating_;
  uint32_t* packed_ = nullptr;
  bool done_ = false;
};

/// The most triangles of `tri` that any one of the n trunks is a vertex of.
uint64_t mostTrianglesPerTrunk(const std::vector<MatchTriangle>& tri, size_t n) {
  std::vector<uint32_t> per(n, 0);
  uint32_t most = 0;
  for (const MatchTriangle& m : tri) {
    for (const int v : m.t.v) {
      if (v >= 0 && static_cast<size_t>(v) < n) most = std::max(most, ++per[v]);
    }
  }
  return most;
}

/// The candidate triangles (sorted by len[0]) whose longest edge can pass Cons_l with l:
/// [first, second). A pair whose longest edges disagree could still give weak support through
/// e2/e3 in Alg. 1; dtif drops that evidence on purpose: such edge-only coincidences are the
/// bulk of random support.
/// The query triangles come sorted by longest edge too, and both bounds grow with l, so each
/// window starts where the last one did and slides forward: a few steps instead of two binary
/// searches (a mispredicted branch per halving) per query triangle. Any l below the last one
/// is searched afresh; the windows are the same either way.
class LengthWindows {
 public:
  LengthWindows(const std::vector<float>& len0, const MatcherParams& params)
      : len0_(len0), rel_(params.edge_rel_tol), abs_(params.edge_abs_tol_m) {}
  std::pair<size_t, size_t> operator()(double l) {
    const double lo = std::min(l - abs_, l * (1.0 - rel_));
    const double hi = std::max(l + abs_, l / (1.0 - rel_));
    const size_t n = len0_.size();
    if (!(l >= last_)) from_ = 0, to_ = 0;  // NaN too: from the start
    last_ = l;
    while (from_ < n && len0_[from_] < lo) ++from_;
    to_ = std::max(to_, from_);
    while (to_ < n && !(hi < len0_[to_])) ++to_;
    return {from_, to_};
  }

 private:
  const std::vector<float>& len0_;
  double rel_, abs_;
  double last_ = -std::numeric_limits<double>::infinity();
  size_t from_ = 0, to_ = 0;
};

/// f(k, m[k]) for every k < n with m[k] != 0, in order. With SSE2, the nonzero bytes of 16 at
/// a time become bits, visited lowest first: no branch per byte (about one mask byte in ten is
/// nonzero in a lattice stand, at random places, which the per-byte branch mispredicted).
template <class F>
void forEachNonzero(const uint8_t* m, size_t n, const F& f) {
  size_t j = 0;
#ifdef __SSE2__
  const __m128i zero = _mm_setzero_si128();
  for (; j + 16 <= n; j += 16) {
    const __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(m + j));
    unsigned bits = ~static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(v, zero))) & 0xffffu;
    while (bits != 0) {
      const size_t k = j + static_cast<size_t>(__builtin_ctz(bits));
      f(k, m[k]);
      bits &= bits - 1;
    }
  }
#endif
  for (; j + 8 <= n; j += 8) {
    uint64_t word = 0;
    std::memcpy(&word, m + j, sizeof word);
    if (word == 0) continue;
    for (size_t k = j; k < j + 8; ++k) {
      if (m[k] != 0) f(k, m[k]);
    }
  }
  for (; j < n; ++j) {
    if (m[j] != 0) f(j, m[j]);
  }
}

}  // namespace

VertexSupport accumulateSupport(const std::vector<MatchTriangle>& tq,
                                const std::vector<MatchTriangle>& tc, size_t nq, size_t nc,
                                const MatcherParams& params, size_t* triangle_pairs,
                                const std::vector<ConsistencyBounds>* bq) {
  std::vector<ConsistencyBounds> own;
  if (!bq) own = consistencyBounds(tq, params);
  const std::vector<ConsistencyBounds>& bounds = bq ? *bq : own;
  // Flat matrices: submaps hold tens to a few hundred trunks. The touched list lets the
  // weights visit only non-zero entries.
  VertexSupport sup;
  sup.nq = nq;
  sup.nc = nc;
  SupportScratch& scratch = supportScratch();
  // A vertex pair's count rises at most once per pair of triangles that hold its two trunks,
  // by at most 2 (weak: a vertex ends two edges). Below 65535 that way, no count saturates.
  const uint64_t reach = 2 * mostTrianglesPerTrunk(tq, nq) * mostTrianglesPerTrunk(tc, nc);
  SupportCounts counts(&scratch.packed, &sup, reach >= 0xffffu);
  scratch.cols.assign(tc);
  LengthWindows window_of(scratch.cols.v[0], params);
  for (size_t i = 0; i < tq.size(); ++i) {
    const MatchTriangle& mq = tq[i];
    const auto [from, to] = window_of(mq.t.len[0]);
    *triangle_pairs += to - from;
    if (!bounds[i].exact) {
      for (size_t j = from; j < to; ++j) {
        const Triangle &q = mq.t, &c = tc[j].t;
        const bool faces = mq.delaunay && tc[j].delaunay;
        const int m = faces ? edgeMask(q, c, params) : fullyConsistent(q, c, params) * 7;
        if (m != 0) counts.add(q, c, m);
      }
      continue;
    }
    // Masks first (vectorised), then only the pairs that give support: in a lattice stand
    // ~125,000 pairs per candidate fall in the windows and under a tenth of them support.
    boundsMasks(scratch.cols, bounds[i], mq.delaunay, from, to, &scratch.mask);
    const MatchTriangle* window = tc.data() + from;  // a lambda cannot capture `from` (C++17)
    const SupportCounts::Rows rows = counts.rowsOf(mq.t);
    if (counts.saturating()) {
      forEachNonzero(scratch.mask.data(), to - from,
                     [&](size_t k, uint8_t m) { counts.addAt<true>(rows, window[k].t, m); });
    } else {
      forEachNonzero(scratch.mask.data(), to - from,
                     [&](size_t k, uint8_t m) { counts.addAt<false>(rows, window[k].t, m); });
    }
  }
  counts.out();
  return sup;
}

namespace {

/// Eqs. (3.8)-(3.9) for a vertex pair's support counts (s, w): whether the pair counts, and
/// its weight. log1p of the small counts comes from a table: the same values without a libm
/// call per pair.
class SupportWeight {
 public:
  explicit SupportWeight(const MatcherParams& p)
      : alpha_s_(p.alpha_s), alpha_w_(p.alpha_w), weak_min_(p.weak_support_min) {}
  bool counts(int s, int w) const { return (s > 0) | (w > weak_min_); }  // no branch
  double operator()(int s, int w) const { return 1.0 + alpha_s_ * log1p(s) + alpha_w_ * log1p(w); }

 private:
  static double log1p(int n) {
    static const std::array<double, 256> kTable = [] {
      std::array<double, 256> t{};
      for (size_t i = 0; i < t.size(); ++i) t[i] = std::log1p(static_cast<double>(i));
      return t;
    }();
    return n < static_cast<int>(kTable.size()) ? kTable[static_cast<size_t>(n)]
                                               : std::log1p(static_cast<double>(n));
  }
  double alpha_s_, alpha_w_;
  int weak_min_;
};

/// Which supported pairs are among the `keep` heaviest (Eq. 3.10; ties by index, so the choice
/// is total): decided per pair of counts (s, w) from a histogram of the counts, as a pair's
/// weight is a function of its counts. A selection among the pairs themselves cost more: a
/// lattice stand's candidate has ~15,000 supported pairs, all of counts below 64, of which
/// 400 are kept. Pairs are then asked in index order (kept()).
class HeaviestPairs {
 public:
  HeaviestPairs(const VertexSupport& sup, const SupportWeight& weight, size_t keep)
      : sup_(sup), weight_(weight), code_(sup.touched.size()), verdict_(kCodes, kDrop) {
    std::vector<uint32_t> hist(kCodes, 0);
    std::vector<double> large;  // weights of counts of kSide and more
    for (size_t i = 0; i < sup.touched.size(); ++i) {
      const uint32_t k = sup.touched[i];
      const int s = sup.strong[k], w = sup.weak[k];
      uint16_t c = kUncounted;
      if (s >= kSide || w >= kSide) {
        if (weight.counts(s, w)) large.push_back(weight(s, w)), c = kLarge;
      } else {
        // No branch (a coin toss here): the cell when the pair counts, else kUncounted.
        const int counted = weight.counts(s, w);
        c = static_cast<uint16_t>(kUncounted + counted * (cell(s, w) - int{kUncounted}));
      }
      code_[i] = c;
      ++hist[c];
    }
    verdict_[kLarge] = kWeigh;
    if (sup.touched.size() - hist[kUncounted] <= keep) {
      std::fill(verdict_.begin(), verdict_.begin() + kUncounted, kTake);
      verdict_[kLarge] = kTake;
      return;
    }
    cutAt(levels(hist, large), keep);
    for (int s = 0; s < kSide; ++s) {
      for (int w = 0; w < kSide; ++w) {
        if (!hist[cell(s, w)]) continue;
        verdict_[cell(s, w)] = verdictOf(weight(s, w));
      }
    }
  }
  /// Whether sup.touched[i] is kept; ask in order of i (the ties go to the first ones).
  bool kept(size_t i) {
    uint8_t v = verdict_[code_[i]];
    if (v == kWeigh) {
      const uint32_t k = sup_.touched[i];
      v = verdictOf(weight_(sup_.strong[k], sup_.weak[k]));
    }
    if (v != kTie) return v == kTake;
    if (ties_ == 0) return false;
    --ties_;
    return true;
  }

 private:
  static constexpr int kSide = 64;
  // Codes of a pair: its cell (s, w) below kSide, or one of these.
  static constexpr uint16_t kUncounted = kSide * kSide, kLarge = kUncounted + 1;
  static constexpr size_t kCodes = kLarge + 1;
  enum : uint8_t { kDrop, kTake, kTie, kWeigh };
  static uint16_t cell(int s, int w) { return static_cast<uint16_t>(s * kSide + w); }
  uint8_t verdictOf(double x) const { return x > cut_ ? kTake : x == cut_ ? kTie : kDrop; }
  /// (weight, pairs) of the counted pairs, heaviest first.
  std::vector<std::pair<double, size_t>> levels(const std::vector<uint32_t>& hist,
                                                const std::vector<double>& large) const {
    std::vector<std::pair<double, size_t>> out;
    for (int s = 0; s < kSide; ++s) {
      for (int w = 0; w < kSide; ++w) {
        if (hist[cell(s, w)]) out.emplace_back(weight_(s, w), hist[cell(s, w)]);
      }
    }
    for (const double x : large) out.emplace_back(x, 1);
    std::sort(out.begin(), out.end(),
              [](const auto& a, const auto& b) { return a.first > b.first; });
    return out;
  }
  /// The weight of the keep-th heaviest pair, and how many of that weight are kept.
  void cutAt(const std::vector<std::pair<double, size_t>>& levels, size_t keep) {
    size_t above = 0;
    for (size_t i = 0; i < levels.size();) {
      size_t n = 0, j = i;
      for (; j < levels.size() && levels[j].first == levels[i].first; ++j) n += levels[j].second;
      if (above + n >= keep) {
        cut_ = levels[i].first;
        ties_ = keep - above;
        return;
      }
      above += n;
      i = j;
    }
  }
  const VertexSupport& sup_;
  const SupportWeight& weight_;
  std::vector<uint16_t> code_;    // per touched pair
  std::vector<uint8_t> verdict_;  // per code
  double cut_ = 0.0;
  size_t ties_ = 0;
};

}  // namespace

std::vector<Correspondence> weightedCorrespondences(const VertexSupport& support,
                                                    const Descriptor& query,
                                                    const Descriptor& candidate,
                                                    const MatcherParams& params) {
  const SupportWeight weight(params);
  const size_t max_keep = static_cast<size_t>(params.max_correspondences);
  HeaviestPairs heaviest(support, weight, max_keep);
  // (omega, flat index) of the kept pairs, in index order, then heaviest first (Eq. 3.10); the
  // flat index orders by query, then candidate trunk, so the order is total and deterministic.
  std::vector<std::pair<double, uint32_t>> weighted;
  weighted.reserve(std::min(support.touched.size(), max_keep));
  for (size_t i = 0; i < support.touched.size(); ++i) {
    if (!heaviest.kept(i)) continue;
    const uint32_t k = support.touched[i];
    weighted.emplace_back(weight(support.strong[k], support.weak[k]), k);
  }
  std::sort(weighted.begin(), weighted.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  const size_t keep = weighted.size();
  std::vector<Correspondence> out(keep);
  const size_t nc = support.nc;
  for (size_t i = 0; i < keep; ++i) {
    const uint32_t k = weighted[i].second;
    Correspondence& cr = out[i];
    cr.iq = static_cast<int>(k / nc);
    cr.ic = static_cast<int>(k % nc);
    const TrunkLandmark& a = query.trunks[cr.iq];
    const TrunkLandmark& b = candidate.trunks[cr.ic];
    cr.pq = Eigen::Vector3d(a.x, a.y, a.z);
    cr.pc = Eigen::Vector3d(b.x, b.y, b.z);
    cr.z_ok = a.base_seen && b.base_seen;
    cr.strong = support.strong[k];
    cr.weak = support.weak[k];
    cr.w = weighted[i].first;
  }
  return out;
}

}  // namespace matcher_stages

std::vector<Correspondence> buildCorrespondences(
    const Descriptor& query, const Descriptor& candidate, const MatcherParams& params,
    MatchStats* stats, const std::vector<MatchTriangle>* query_triangles,
    const std::vector<MatchTriangle>* candidate_triangles,
    const std::vector<ConsistencyBounds>* query_bounds) {
  MatchStats local;
  MatchStats& st = stats ? *stats : local;
  st = MatchStats{};
  if (!matcher_stages::passesScreening(query, candidate, params, &st)) return {};
  const size_t nq = query.trunks.size(), nc = candidate.trunks.size();
  if (nq == 0 || nc == 0 || query.triangles.empty() || candidate.triangles.empty()) return {};
  std::vector<MatchTriangle> own_q, own_c;
  if (!query_triangles) own_q = matchTriangles(query, params.neighbour_triangles);
  if (!candidate_triangles) own_c = matchTriangles(candidate, params.neighbour_triangles);
  const std::vector<MatchTriangle>& tq = query_triangles ? *query_triangles : own_q;
  const std::vector<MatchTriangle>& tc = candidate_triangles ? *candidate_triangles : own_c;
  const matcher_stages::VertexSupport support =
      matcher_stages::accumulateSupport(tq, tc, nq, nc, params, &st.triangle_pairs, query_bounds);
  return matcher_stages::weightedCorrespondences(support, query, candidate, params);
}

}  // namespace dtif
