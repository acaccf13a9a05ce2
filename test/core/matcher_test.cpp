#include "dtif/core/matching/matcher.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>

#include "core/match_test_utils.h"
#include "dtif/core/matching/matcher_stages.h"

namespace dtif {
namespace {

/// A descriptor made by hand: the given faces, identical flat histograms (screening passes).
Descriptor handMade(const Trunks& trunks, const std::vector<std::array<int, 3>>& faces) {
  Descriptor d;
  d.trunks = trunks;
  for (const auto& f : faces)
    d.triangles.push_back(makeCanonicalTriangle(trunks, f[0], f[1], f[2]));
  std::sort(d.triangles.begin(), d.triangles.end(),
            [](const Triangle& a, const Triangle& b) { return a.len[0] < b.len[0]; });
  d.edge_hist.assign(16, 1.0f / 16);
  d.radius_hist.assign(10, 0.1f);
  d.valid = true;
  return d;
}

const Correspondence* find(const std::vector<Correspondence>& c, int iq, int ic) {
  for (const Correspondence& k : c) {
    if (k.iq == iq && k.ic == ic) return &k;
  }
  return nullptr;
}

// Query: one 3-4-5 triangle q0=(0,0) r.1, q1=(4,0) r.2, q2=(0,3) r.3.
// Canonical: e1 = q1q2 (5), e2 = q0q1 (4), e3 = q0q2 (3); I = (q1, q0, q2).
// Candidate: c0..c2 the same triangle (all 3 edges verified -> strong), and c3..c5 a 5-4-2
// triangle P=c3 (20,0) r.2, Q=c4 (25,0) r.3, R=c5 (23.7, 1.52) r.1 with e1 = PQ (5),
// e2 = PR (4), e3 = RQ (2): I = (P, R, Q) = (c3, c5, c4). Against the query triangle e1 and
// e2 verify, e3 (2 vs 3 m) does not: weak support (Eq. 3.7)
//   e1 (positions 0, 2): (q1, c3) += 1, (q2, c4) += 1
//   e2 (positions 0, 1): (q1, c3) += 1, (q0, c5) += 1
// so E^w = {(q1,c3): 2, (q2,c4): 1, (q0,c5): 1} and E^s = {(q1,c1), (q0,c0), (q2,c2): 1}.
struct HandCase {
  Descriptor q, c;
  HandCase() {
    q = handMade({{0, 0, 0, .1}, {4, 0, 0, .2}, {0, 3, 0, .3}}, {{0, 1, 2}});
    const double ry = std::sqrt(16.0 - 3.7 * 3.7);
    c = handMade({{0, 0, 0, .1},
                  {4, 0, 0, .2},
                  {0, 3, 0, .3},
                  {20, 0, 0, .2},
                  {25, 0, 0, .3},
                  {23.7, ry, 0, .1}},
                 {{0, 1, 2}, {3, 4, 5}});
  }
};

TEST(Matcher, HandMadeCanonicalOrder) {
  HandCase h;
  EXPECT_EQ(h.q.triangles[0].v, (std::array<int, 3>{1, 0, 2}));
  ASSERT_EQ(h.c.triangles.size(), 2u);
  for (const Triangle& t : h.c.triangles) {
    if (t.v[0] >= 3) {
      EXPECT_EQ(t.v, (std::array<int, 3>{3, 5, 4}));
    }
  }
}

TEST(Matcher, HandMadeStrongAndWeakSupportCounts) {
  HandCase h;
  MatcherParams p;
  p.neighbour_triangles = 0;  // the paper's Alg. 1 on the Delaunay faces
  p.weak_support_min = 0;     // keep every pair with any support to read E^w back
  MatchStats st;
  const auto corrs = buildCorrespondences(h.q, h.c, p, &st);
  EXPECT_EQ(st.triangle_pairs, 2u);  // both candidate faces have a 5 m longest edge
  ASSERT_EQ(corrs.size(), 6u);
  const std::map<std::pair<int, int>, std::pair<int, int>> expected = {
      {{1, 1}, {1, 0}}, {{0, 0}, {1, 0}}, {{2, 2}, {1, 0}},
      {{1, 3}, {0, 2}}, {{2, 4}, {0, 1}}, {{0, 5}, {0, 1}}};
  for (const auto& [pair, support] : expected) {
    const Correspondence* k = find(corrs, pair.first, pair.second);
    ASSERT_NE(k, nullptr) << pair.first << "," << pair.second;
    EXPECT_EQ(k->strong, support.first) << pair.first << "," << pair.second;
    EXPECT_EQ(k->weak, support.second) << pair.first << "," << pair.second;
    // Eq. (3.9)
    EXPECT_NEAR(k->w,
                1.0 + p.alpha_s * std::log(1.0 + k->strong) + p.alpha_w * std::log(1.0 + k->weak),
                1e-12);
  }
  // Heaviest first: the strong pairs (1 + log 2) outweigh the weak ones (<= 1 + 0.25 log 3).
  for (int i = 0; i < 3; ++i) EXPECT_EQ(corrs[i].strong, 1);
  EXPECT_EQ(corrs[3].iq, 1);  // (q1, c3) has the larger weak count
  EXPECT_EQ(corrs[3].ic, 3);
  EXPECT_EQ(corrs[0].pq, Eigen::Vector3d(h.q.trunks[corrs[0].iq].x, h.q.trunks[corrs[0].iq].y, 0));
}

TEST(Matcher, WeakSupportThresholdIsStrict) {
  // Eq. (3.8): E^w > tau_w. With tau_w = 1 only (q1, c3) with E^w = 2 survives of the weak ones.
  HandCase h;
  MatcherParams p;
  p.neighbour_triangles = 0;
  p.weak_support_min = 1;
  auto corrs = buildCorrespondences(h.q, h.c, p);
  EXPECT_EQ(corrs.size(), 4u);
  EXPECT_NE(find(corrs, 1, 3), nullptr);
  EXPECT_EQ(find(corrs, 2, 4), nullptr);
  p.weak_support_min = 2;  // default: no weak-only pair passes
  corrs = buildCorrespondences(h.q, h.c, p);
  EXPECT_EQ(corrs.size(), 3u);
  EXPECT_EQ(find(corrs, 1, 3), nullptr);
}

TEST(Matcher, RadiusInconsistencyTurnsStrongIntoWeak) {
  HandCase h;
  h.c.trunks[2].r = 0.6;  // c2 (position 2 of the first face) no longer matches q2's 0.3
  h.c.triangles.clear();
  for (auto f : {std::array<int, 3>{0, 1, 2}}) {
    h.c.triangles.push_back(makeCanonicalTriangle(h.c.trunks, f[0], f[1], f[2]));
  }
  MatcherParams p;
  p.neighbour_triangles = 0;
  p.weak_support_min = 0;
  const auto corrs = buildCorrespondences(h.q, h.c, p);
  // Edges touching position 2 (e1, e3) fail; only e2 (positions 0, 1) verifies.
  ASSERT_EQ(corrs.size(), 2u);
  const Correspondence* a = find(corrs, 1, 1);
  const Correspondence* b = find(corrs, 0, 0);
  ASSERT_TRUE(a && b);
  EXPECT_EQ(a->strong, 0);
  EXPECT_EQ(a->weak, 1);
  EXPECT_EQ(b->weak, 1);
}

TEST(Matcher, ScreeningByHistogramIntersection) {
  EXPECT_NEAR(histogramIntersection({0.5f, 0.5f, 0.0f}, {0.25f, 0.25f, 0.5f}), 0.5, 1e-7);
  EXPECT_NEAR(histogramIntersection({1.0f, 0.0f}, {1.0f, 0.0f}), 1.0, 1e-7);
  EXPECT_EQ(histogramIntersection({1.0f}, {0.5f, 0.5f}), 0.0);  // different binning
  HandCase h;
  h.c.edge_hist.assign(16, 0.0f);
  h.c.edge_hist[0] = 1.0f;  // s_e = 1/16 < tau_s^e
  MatchStats st;
  EXPECT_TRUE(buildCorrespondences(h.q, h.c, MatcherParams{}, &st).empty());
  EXPECT_TRUE(st.screened_out);
  EXPECT_NEAR(st.edge_hist_sim, 1.0 / 16, 1e-6);
}

/// Reference: Alg. 1 over all triangle pairs, restricted (like dtif) to pairs whose longest
/// edges are consistent. The indexed matcher must visit every such pair and count identically.
std::map<std::pair<int, int>, std::pair<int, int>> naiveSupport(const Descriptor& q,
                                                                const Descriptor& c,
                                                                const MatcherParams& p) {
  auto cons = [](double a, double b, double rel, double abs_tol) {
    const double d = std::fabs(a - b);
    return d <= abs_tol || d <= rel * std::max(a, b);
  };
  std::map<std::pair<int, int>, std::pair<int, int>> s;
  for (const Triangle& tq : q.triangles) {
    for (const Triangle& tc : c.triangles) {
      if (!cons(tq.len[0], tc.len[0], p.edge_rel_tol, p.edge_abs_tol_m)) continue;
      int mask = 0, n = 0;
      for (int a = 0; a < 3; ++a) {
        const int u = kEdgeEnds[a][0], v = kEdgeEnds[a][1];
        if (cons(tq.len[a], tc.len[a], p.edge_rel_tol, p.edge_abs_tol_m) &&
            cons(tq.r[u], tc.r[u], p.radius_rel_tol, p.radius_abs_tol_m) &&
            cons(tq.r[v], tc.r[v], p.radius_rel_tol, p.radius_abs_tol_m)) {
          mask |= 1 << a;
          ++n;
        }
      }
      if (n == 3) {
        for (int b = 0; b < 3; ++b) s[{tq.v[b], tc.v[b]}].first++;
      } else {
        for (int a = 0; a < 3; ++a) {
          if (!(mask >> a & 1)) continue;
          for (int e : kEdgeEnds[a]) s[{tq.v[e], tc.v[e]}].second++;
        }
      }
    }
  }
  return s;
}

TEST(Matcher, IndexedMatcherEqualsNaiveReferenceOnRandomStands) {
  std::mt19937 rng(17);
  for (int trial = 0; trial < 5; ++trial) {
    const Trunks world = test::randomStand(rng, 60, 60, 700);
    const Descriptor q = buildDescriptor(
        test::observe(rng, world, {25, 25}, test::poseXyYaw(25, 25, 0, 1.0)), DescriptorParams{});
    const Descriptor c = buildDescriptor(
        test::observe(rng, world, {32, 28}, test::poseXyYaw(30, 30, 0, -2.0)), DescriptorParams{});
    MatcherParams p;
    p.neighbour_triangles = 0;  // the reference visits the Delaunay faces
    p.weak_support_min = 0;
    p.max_correspondences = 1000000;
    p.min_edge_hist_sim = 0;
    p.min_radius_hist_sim = 0;
    MatchStats st;
    const auto corrs = buildCorrespondences(q, c, p, &st);
    const auto ref = naiveSupport(q, c, p);
    EXPECT_LT(st.triangle_pairs, q.triangles.size() * c.triangles.size() / 4)
        << "the length index should skip most pairs";
    ASSERT_EQ(corrs.size(), ref.size());
    for (const Correspondence& k : corrs) {
      const auto it = ref.find({k.iq, k.ic});
      ASSERT_NE(it, ref.end());
      EXPECT_EQ(k.strong, it->second.first);
      EXPECT_EQ(k.weak, it->second.second);
    }
    for (size_t i = 1; i < corrs.size(); ++i) EXPECT_GE(corrs[i - 1].w, corrs[i].w);
  }
}

TEST(Matcher, MaxCorrespondencesKeepsTheHeaviest) {
  HandCase h;
  MatcherParams p;
  p.neighbour_triangles = 0;
  p.weak_support_min = 0;
  p.max_correspondences = 2;
  const auto corrs = buildCorrespondences(h.q, h.c, p);
  ASSERT_EQ(corrs.size(), 2u);
  EXPECT_EQ(corrs[0].strong, 1);
  EXPECT_EQ(corrs[1].strong, 1);
}

/// Two submaps that share only part of their trunks share few Delaunay faces (a trunk seen by
/// one of them only changes its neighbours' faces) but many nearest-neighbour triangles.
TEST(Matcher, NeighbourTrianglesFindCorrectPairsWhenFewTrunksAreShared) {
  std::mt19937 rng(41);
  test::ObservationNoise nz;
  nz.miss_ratio = 0.45;  // each side misses 45 %: ~30 % of the detections are shared
  int correct[2] = {0, 0}, wrong[2] = {0, 0};
  for (int trial = 0; trial < 10; ++trial) {
    const Trunks world = test::randomStand(rng, 60, 60, 700);
    const Pose T_w_q = test::poseXyYaw(25, 25, 0, 1.0), T_w_c = test::poseXyYaw(30, 30, 0, -2.0);
    const Descriptor q =
        buildDescriptor(test::observe(rng, world, {25, 25}, T_w_q, nz), DescriptorParams{});
    const Descriptor c =
        buildDescriptor(test::observe(rng, world, {32, 28}, T_w_c, nz), DescriptorParams{});
    const Pose T_c_q = T_w_c.inverse() * T_w_q;
    for (int k : {0, 1}) {
      MatcherParams p;
      p.neighbour_triangles = k ? 4 : 0;
      for (const Correspondence& m : buildCorrespondences(q, c, p)) {
        const bool ok = ((T_c_q * m.pq) - m.pc).head<2>().norm() < 0.3;
        (ok ? correct : wrong)[k]++;
      }
    }
  }
  std::printf("[ info ] correct/wrong pairs: Delaunay only %d/%d, with neighbour triangles %d/%d\n",
              correct[0], wrong[0], correct[1], wrong[1]);
  EXPECT_GE(correct[1], 1.4 * correct[0]);
  // More evidence, not more noise: the share of correct pairs does not drop much.
  EXPECT_GT(static_cast<double>(correct[1]) / (correct[1] + wrong[1]),
            0.95 * static_cast<double>(correct[0]) / std::max(1, correct[0] + wrong[0]));
}

// --- Stages (matcher_stages.h) ---

TEST(MatcherStages, ScreeningSetsBothSimilaritiesAndRejectsBelowEitherThreshold) {
  HandCase h;
  const MatcherParams p;
  MatchStats st;
  EXPECT_TRUE(matcher_stages::passesScreening(h.q, h.c, p, &st));
  EXPECT_NEAR(st.edge_hist_sim, 1.0, 1e-6);
  EXPECT_NEAR(st.radius_hist_sim, 1.0, 1e-6);
  EXPECT_FALSE(st.screened_out);
  h.c.radius_hist.assign(10, 0.0f);
  h.c.radius_hist[0] = 1.0f;  // intersection 0.1 < 0.4
  st = MatchStats{};
  EXPECT_FALSE(matcher_stages::passesScreening(h.q, h.c, p, &st));
  EXPECT_NEAR(st.radius_hist_sim, 0.1, 1e-6);
  EXPECT_TRUE(st.screened_out);
}

TEST(MatcherStages, ConsistentEdgesFollowEq34) {
  HandCase h;
  const MatcherParams p;
  const Triangle q = makeCanonicalTriangle(h.q.trunks, 0, 1, 2);
  const Triangle same = makeCanonicalTriangle(h.c.trunks, 0, 1, 2);
  const Triangle other = makeCanonicalTriangle(h.c.trunks, 3, 4, 5);
  EXPECT_EQ(matcher_stages::consistentEdges(q, same, p), 0b111);
  EXPECT_EQ(matcher_stages::consistentEdges(q, other, p), 0b011);  // e3: 2 m vs 3 m
  Trunks fat = h.c.trunks;
  fat[2].r = 0.6;  // at position 2 of `same`: e1 and e3 end there
  EXPECT_EQ(matcher_stages::consistentEdges(q, makeCanonicalTriangle(fat, 0, 1, 2), p), 0b010);
}

TEST(MatcherStages, AccumulateSupportCountsStrongAndWeakVertexSupport) {
  HandCase h;
  MatcherParams p;
  p.neighbour_triangles = 0;
  const auto tq = matchTriangles(h.q, 0), tc = matchTriangles(h.c, 0);
  size_t pairs = 0;
  const matcher_stages::VertexSupport sup =
      matcher_stages::accumulateSupport(tq, tc, 3, 6, p, &pairs);
  EXPECT_EQ(pairs, 2u);
  ASSERT_EQ(sup.strong.size(), 18u);
  ASSERT_EQ(sup.weak.size(), 18u);
  EXPECT_EQ(sup.touched.size(), 6u);
  auto at = [](const std::vector<uint16_t>& m, int iq, int ic) { return m[iq * 6 + ic]; };
  int strong_sum = 0, weak_sum = 0;
  for (int k = 0; k < 18; ++k) strong_sum += sup.strong[k], weak_sum += sup.weak[k];
  EXPECT_EQ(strong_sum, 3);
  EXPECT_EQ(weak_sum, 4);
  EXPECT_EQ(at(sup.strong, 1, 1), 1);
  EXPECT_EQ(at(sup.strong, 0, 0), 1);
  EXPECT_EQ(at(sup.strong, 2, 2), 1);
  EXPECT_EQ(at(sup.weak, 1, 3), 2);
  EXPECT_EQ(at(sup.weak, 2, 4), 1);
  EXPECT_EQ(at(sup.weak, 0, 5), 1);
  // Neighbour triangles give no weak support: the same pair marked as non-Delaunay.
  std::vector<MatchTriangle> tq_nb = tq;
  for (MatchTriangle& t : tq_nb) t.delaunay = false;
  const auto sup_nb = matcher_stages::accumulateSupport(tq_nb, tc, 3, 6, p, &pairs);
  EXPECT_EQ(pairs, 4u);  // added to
  EXPECT_EQ(sup_nb.touched.size(), 3u);
  for (uint16_t w : sup_nb.weak) EXPECT_EQ(w, 0);
}

TEST(MatcherStages, AccumulateSupportCountsExactlyAndSaturatesAt65535) {
  // n copies of the query's triangle against n of the candidate's same triangle (strong, every
  // vertex pair n^2 times) or of its other one (weak through e1 and e2: vertex 0 ends both, so it
  // gets 2 n^2, vertices 1 and 2 get n^2). The counts are exact below 65535 and stop there.
  HandCase h;
  const MatcherParams p;
  const MatchTriangle q{makeCanonicalTriangle(h.q.trunks, 0, 1, 2), true};
  const MatchTriangle same{makeCanonicalTriangle(h.c.trunks, 0, 1, 2), true};
  const MatchTriangle other{makeCanonicalTriangle(h.c.trunks, 3, 4, 5), true};
  auto at = [](const std::vector<uint16_t>& m, int iq, int ic) { return m[iq * 6 + ic]; };
  for (const int n : {100, 150, 200, 300}) {
    const std::vector<MatchTriangle> tq(n, q), tc_same(n, same), tc_other(n, other);
    const auto expect = [](uint64_t v) {
      return static_cast<uint16_t>(std::min<uint64_t>(v, 65535));
    };
    const uint64_t n2 = static_cast<uint64_t>(n) * n;
    size_t pairs = 0;
    const auto strong = matcher_stages::accumulateSupport(tq, tc_same, 3, 6, p, &pairs);
    for (int v = 0; v < 3; ++v) {
      EXPECT_EQ(at(strong.strong, q.t.v[v], same.t.v[v]), expect(n2)) << n;
    }
    const auto weak = matcher_stages::accumulateSupport(tq, tc_other, 3, 6, p, &pairs);
    EXPECT_EQ(at(weak.weak, q.t.v[0], other.t.v[0]), expect(2 * n2)) << n;
    EXPECT_EQ(at(weak.weak, q.t.v[1], other.t.v[1]), expect(n2)) << n;
    EXPECT_EQ(at(weak.weak, q.t.v[2], other.t.v[2]), expect(n2)) << n;
    EXPECT_EQ(at(weak.strong, q.t.v[0], other.t.v[0]), 0) << n;
  }
}

TEST(MatcherStages, WeightedCorrespondencesKeepSupportedPairsHeaviestFirst) {
  HandCase h;
  MatcherParams p;  // weak_support_min = 2
  matcher_stages::VertexSupport sup;
  sup.nq = 3;
  sup.nc = 6;
  sup.strong.assign(18, 0);
  sup.weak.assign(18, 0);
  sup.weak[1 * 6 + 3] = 3;  // kept: E^w > tau_w
  sup.weak[2 * 6 + 4] = 2;  // dropped: E^w = tau_w
  sup.strong[0 * 6 + 5] = 1;
  sup.weak[0 * 6 + 5] = 1;
  sup.touched = {1 * 6 + 3, 2 * 6 + 4, 0 * 6 + 5};
  const auto corrs = matcher_stages::weightedCorrespondences(sup, h.q, h.c, p);
  ASSERT_EQ(corrs.size(), 2u);
  EXPECT_EQ(corrs[0].iq, 0);  // 1 + log 2 + 0.25 log 2 outweighs 1 + 0.25 log 4
  EXPECT_EQ(corrs[0].ic, 5);
  EXPECT_NEAR(corrs[0].w, 1.0 + std::log(2.0) + 0.25 * std::log(2.0), 1e-12);
  EXPECT_EQ(corrs[1].iq, 1);
  EXPECT_EQ(corrs[1].ic, 3);
  EXPECT_NEAR(corrs[1].w, 1.0 + 0.25 * std::log(4.0), 1e-12);
  EXPECT_EQ(corrs[1].pc, Eigen::Vector3d(20, 0, 0));
  p.max_correspondences = 2;
  sup.weak[2 * 6 + 4] = 5;  // now kept, but only the heaviest two are
  const auto top = matcher_stages::weightedCorrespondences(sup, h.q, h.c, p);
  ASSERT_EQ(top.size(), 2u);
  EXPECT_EQ(top[1].iq, 2);  // 1 + 0.25 log 6 > 1 + 0.25 log 4
}

// The heaviest K by a full sort of all supported pairs (weight, then index): the definition
// the histogram cut of weightedCorrespondences must reproduce exactly.
std::vector<std::pair<int, int>> heaviestBySort(const matcher_stages::VertexSupport& sup,
                                                const MatcherParams& p) {
  std::vector<std::pair<double, uint32_t>> all;
  for (uint32_t k : sup.touched) {
    const int s = sup.strong[k], w = sup.weak[k];
    if (s > 0 || w > p.weak_support_min)
      all.emplace_back(1.0 + p.alpha_s * std::log1p(s) + p.alpha_w * std::log1p(w), k);
  }
  std::sort(all.begin(), all.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  all.resize(std::min(all.size(), static_cast<size_t>(p.max_correspondences)));
  std::vector<std::pair<int, int>> out;
  for (const auto& [w, k] : all) out.emplace_back(k / sup.nc, k % sup.nc);
  return out;
}

TEST(MatcherStages, WeightedCorrespondencesCutMatchesAFullSort) {
  // Many pairs of few distinct counts (ties at every cut, as in a lattice stand), some counts
  // of 64 and more (outside the histogram), and cuts from 1 to more than all pairs.
  HandCase h;
  std::mt19937 rng(7);
  matcher_stages::VertexSupport sup;
  sup.nq = 334;  // 2,004 vertex pairs
  sup.nc = 6;
  sup.strong.assign(sup.nq * sup.nc, 0);
  sup.weak.assign(sup.nq * sup.nc, 0);
  for (size_t k = 0; k < sup.strong.size(); ++k) {
    if (rng() % 5 == 0) continue;  // untouched
    const uint32_t r = rng() % 100;
    sup.strong[k] = static_cast<uint16_t>(r < 50 ? 0 : r < 97 ? rng() % 4 : 60 + rng() % 300);
    sup.weak[k] = static_cast<uint16_t>(r == 98 ? 64 + rng() % 2000 : rng() % 8);
    if (sup.strong[k] || sup.weak[k]) sup.touched.push_back(static_cast<uint32_t>(k));
  }
  // HandCase's descriptors hold 3 and 6 trunks; the correspondences' indices are what is
  // compared here, so the trunks are repeated to cover every index.
  h.q.trunks.resize(sup.nq, h.q.trunks[0]);
  h.c.trunks.resize(sup.nc, h.c.trunks[0]);
  MatcherParams p;
  for (int keep : {1, 2, 17, 400, 1000, 1500, 100000}) {
    p.max_correspondences = keep;
    const auto got = matcher_stages::weightedCorrespondences(sup, h.q, h.c, p);
    const auto want = heaviestBySort(sup, p);
    ASSERT_EQ(got.size(), want.size()) << "keep " << keep;
    for (size_t i = 0; i < got.size(); ++i) {
      ASSERT_EQ(std::make_pair(got[i].iq, got[i].ic), want[i]) << "keep " << keep << " rank " << i;
    }
  }
}

TEST(Matcher, ParamsValidate) {
  EXPECT_EQ(MatcherParams{}.validate(), "");
  MatcherParams p;
  p.alpha_s = 0.1;  // must exceed alpha_w
  EXPECT_NE(p.validate(), "");
  p = MatcherParams{};
  p.edge_rel_tol = -1;
  EXPECT_NE(p.validate(), "");
  p = MatcherParams{};
  p.min_edge_hist_sim = 2;
  EXPECT_NE(p.validate(), "");
}

}  // namespace
}  // namespace dtif
