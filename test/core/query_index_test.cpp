// The loop query's indexes against brute force: the database's screening index (candidates,
// eligibility) after inserts, a reload and replaceContents, the pose votes' flat table, and
// the best loop of the candidates (query verifies only those that can beat it).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/database/loop_pair.h"
#include "dtif/core/matching/matcher.h"
#include "dtif/core/matching/matcher_stages.h"
#include "dtif/core/matching/pair_vote_stages.h"

namespace dtif {
namespace {

/// Descriptors of random stands under a few robots, stamps 10 s apart per robot.
std::vector<std::shared_ptr<const Descriptor>> randomEntries(int pairs, uint32_t seed) {
  std::vector<std::shared_ptr<const Descriptor>> out;
  const char* robots[] = {"alpha", "bravo", "charlie"};
  int k = 0;
  for (const test::PairCase& pc : test::overlappingPairs(pairs, seed)) {
    for (const Descriptor* d : {&pc.c, &pc.q}) {
      auto e = std::make_shared<Descriptor>(*d);
      e->robot = robots[k % 3];
      e->submap_id = k;
      e->stamp = 10.0 * (k / 3);
      out.push_back(e);
      ++k;
    }
  }
  return out;
}

/// What query's screening keeps, computed entry by entry from the descriptors: (eligible,
/// screened in, candidate ids best first).
std::tuple<size_t, size_t, std::vector<int64_t>> bruteScreening(
    const std::vector<std::shared_ptr<const Descriptor>>& db, const Descriptor& q,
    const LoopDetectorParams& p) {
  std::vector<std::pair<double, size_t>> cands;
  size_t eligible = 0;
  for (size_t i = 0; i < db.size(); ++i) {
    const Descriptor& c = *db[i];
    if (!eligibleLoopPair(q.robot, q.stamp, c.robot, c.stamp, p.database.exclude_recent_s) ||
        (c.robot == q.robot && c.submap_id == q.submap_id)) {
      continue;
    }
    ++eligible;
    const double se = histogramIntersection(q.edge_hist, c.edge_hist);
    const double sr = histogramIntersection(q.radius_hist, c.radius_hist);
    if (se < p.matcher.min_edge_hist_sim || sr < p.matcher.min_radius_hist_sim) continue;
    cands.emplace_back(0.5 * (se + sr), i);
  }
  const size_t screened = cands.size();
  std::sort(cands.begin(), cands.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  std::vector<int64_t> ids;
  for (size_t k = 0; k < cands.size() && k < static_cast<size_t>(p.database.max_candidates); ++k)
    ids.push_back(db[cands[k].second]->submap_id);
  return {eligible, screened, ids};
}

LoopDetectorParams screeningParams() {
  LoopDetectorParams p;
  p.database.max_candidates = 4;  // the ranking decides which few are kept
  p.database.exclude_recent_s = 25.0;
  p.matcher.min_edge_hist_sim = 0.3;
  p.matcher.vote_fallback = false;  // matching is not under test
  return p;
}

void expectScreeningLikeBruteForce(const LoopDetector& det,
                                   const std::vector<std::shared_ptr<const Descriptor>>& db,
                                   const std::vector<std::shared_ptr<const Descriptor>>& queries) {
  for (const auto& q : queries) {
    QueryStats st;
    det.query(*q, &st);
    const auto [eligible, screened, ids] = bruteScreening(db, *q, det.params());
    EXPECT_EQ(st.eligible, eligible) << q->robot << "/" << q->submap_id;
    EXPECT_EQ(st.screened_in, screened) << q->robot << "/" << q->submap_id;
    EXPECT_EQ(st.candidates, ids) << q->robot << "/" << q->submap_id;
  }
}

TEST(QueryIndex, ScreeningEqualsBruteForceAfterInsertReloadAndReplace) {
  const auto entries = randomEntries(12, 77);
  const LoopDetectorParams p = screeningParams();
  LoopDetector det(p);
  std::vector<std::shared_ptr<const Descriptor>> db;
  // Queries: entries already in (their own submap and recent ones of their robot excluded)
  // and a robot the database has never seen.
  std::vector<std::shared_ptr<const Descriptor>> queries;
  for (size_t i = 0; i < entries.size(); ++i) {
    if (i % 5 == 0) {
      queries.push_back(entries[i]);
      auto stranger = std::make_shared<Descriptor>(*entries[i]);
      stranger->robot = "delta";
      queries.push_back(stranger);
    }
    ASSERT_TRUE(det.insert(entries[i]));
    db.push_back(entries[i]);
    if (i % 8 == 7) expectScreeningLikeBruteForce(det, db, queries);  // grows with inserts
  }
  expectScreeningLikeBruteForce(det, db, queries);

  const std::string path = ::testing::TempDir() + "/dtif_query_index.bin";
  det.save(path);
  LoopDetector loaded(p);
  loaded.insert(entries[3]);  // replaced by the load, index included
  loaded.load(path);
  ASSERT_EQ(loaded.size(), db.size());
  expectScreeningLikeBruteForce(loaded, loaded.entries(), queries);

  // Replaced by a smaller database: the index holds only the new entries.
  DatabaseContents half;
  half.entries.assign(db.begin(), db.begin() + db.size() / 2);
  half.odometry.resize(half.entries.size());
  loaded.replaceContents(half);
  expectScreeningLikeBruteForce(loaded, half.entries, queries);
  EXPECT_GT(loaded.memoryBytes(), 0u);
  EXPECT_LT(loaded.memoryBytes(), det.memoryBytes());
}

// A base station that built its database live and one that loaded the same database hold the
// same memory (the soak test compares the two): every entry's match triangles are computed when
// it enters, not on its first match, and memoryBytes counts them.
TEST(QueryIndex, MemoryIsTheSameBuiltLiveOrLoaded) {
  const auto entries = randomEntries(10, 31);
  const LoopDetectorParams p = screeningParams();
  LoopDetector live(p);
  size_t triangle_bytes = 0;
  for (const auto& e : entries) {
    live.query(*e);  // matches some entries before others enter
    ASSERT_TRUE(live.insert(e));
    triangle_bytes +=
        matchTriangles(*e, p.matcher.neighbour_triangles).size() * sizeof(MatchTriangle);
  }
  ASSERT_GT(triangle_bytes, 0u);
  const std::string path = ::testing::TempDir() + "/dtif_query_index_memory.bin";
  live.save(path);
  LoopDetector loaded(p);
  loaded.load(path);
  EXPECT_EQ(loaded.memoryBytes(), live.memoryBytes());
  // The descriptors alone: what memoryBytes counted before the triangles were.
  size_t descriptor_bytes = 0;
  for (const auto& d : entries)
    descriptor_bytes +=
        d->trunks.size() * sizeof(TrunkLandmark) + d->triangles.size() * sizeof(Triangle);
  EXPECT_GE(live.memoryBytes(), descriptor_bytes + triangle_bytes);
  int loops = 0;
  for (const auto& q : entries) {
    const auto a = live.query(*q);
    const auto b = loaded.query(*q);
    ASSERT_EQ(a.has_value(), b.has_value()) << q->robot << "/" << q->submap_id;
    if (!a) continue;
    ++loops;
    EXPECT_EQ(a->candidate_robot, b->candidate_robot);
    EXPECT_EQ(a->candidate_id, b->candidate_id);
  }
  EXPECT_GT(loops, 0);  // the comparison covered loops, not only empty answers
}

// The map merge replays a database in the order live submaps entered: by stamp, then robot name,
// entries of equal stamp and robot in database order.
TEST(QueryIndex, EntriesInStampOrderSortsByStampThenRobot) {
  const auto base = randomEntries(3, 11);  // six valid descriptors
  const std::vector<std::pair<double, std::string>> keys = {{30.0, "bravo"}, {10.0, "charlie"},
                                                            {10.0, "alpha"}, {30.0, "alpha"},
                                                            {10.0, "alpha"}, {5.0, "zulu"}};
  LoopDetector det(screeningParams());
  for (size_t i = 0; i < keys.size(); ++i) {
    auto e = std::make_shared<Descriptor>(*base[i]);
    e->stamp = keys[i].first;
    e->robot = keys[i].second;
    e->submap_id = static_cast<int64_t>(i);
    ASSERT_TRUE(det.insert(e));
  }
  EXPECT_EQ(entriesInStampOrder(det), (std::vector<size_t>{5, 2, 4, 1, 3, 0}));
}

TEST(QueryIndex, ScreeningSkipsEntriesOfAnotherHistogramBinning) {
  auto entries = randomEntries(3, 5);
  auto odd = std::make_shared<Descriptor>(*entries[1]);
  odd->edge_hist.push_back(0.0f);  // another binning: intersection 0, never screened in
  odd->submap_id = 100;
  LoopDetectorParams p = screeningParams();
  p.matcher.min_edge_hist_sim = 0.0;
  p.matcher.min_radius_hist_sim = 0.0;
  LoopDetector det(p);
  std::vector<std::shared_ptr<const Descriptor>> db{entries[0], odd, entries[2]};
  for (const auto& d : db) det.insert(d);
  expectScreeningLikeBruteForce(det, db, {entries[3], entries[4], entries[5]});
}

TEST(QueryIndex, VoteTableEqualsAnOrderedMapThroughGrowth) {
  std::mt19937 rng(11);
  std::uniform_int_distribution<int64_t> yaw(0, 179), xy(-300, 300);
  pair_vote_stages::VoteAccumulator acc;
  acc.reserve(4);  // grows many times over
  std::map<std::tuple<int64_t, int64_t, int64_t>, double> ref;
  std::vector<std::tuple<int64_t, int64_t, int64_t>> first_seen;
  for (int k = 0; k < 20000; ++k) {
    // Bins clustered near a few poses as well as scattered ones, as pose votes are.
    const bool near = k % 3 == 0;
    const auto key = std::make_tuple(near ? yaw(rng) % 4 : yaw(rng), near ? xy(rng) % 3 : xy(rng),
                                     near ? 7 : xy(rng));
    const auto [iyaw, ix, iy] = key;
    pair_vote_stages::VoteBin& b = acc.at(iyaw, ix, iy);
    EXPECT_EQ(std::make_tuple(b.iyaw, b.ix, b.iy), key);
    b.count += 1.0;
    if (ref[key]++ == 0.0) first_seen.push_back(key);
  }
  ASSERT_EQ(acc.bins.size(), ref.size());
  for (size_t i = 0; i < acc.bins.size(); ++i) {  // first vote first, through every rehash
    const pair_vote_stages::VoteBin& b = acc.bins[i];
    EXPECT_EQ(std::make_tuple(b.iyaw, b.ix, b.iy), first_seen[i]);
    EXPECT_EQ(b.count, ref.at(first_seen[i]));
    EXPECT_EQ(acc.find(b.iyaw, b.ix, b.iy), &b);
  }
  EXPECT_EQ(acc.find(5, 1000, 1000), nullptr);
  EXPECT_EQ(pair_vote_stages::VoteAccumulator{}.find(0, 0, 0), nullptr);
}

TEST(QueryIndex, VotesFallInTheBinsOfTheirOwnAtan2) {
  // accumulateVotes bins each vote from an approximate yaw unless that lies within a hair of a
  // bin edge: against every vote binned by its own atan2 and floor, on random directions and
  // on directions whose yaws fall on, or beside (within the approximation's error and far
  // below it), a bin edge.
  const MatcherParams params;
  const int64_t n_yaw = std::llround(360.0 / params.vote_yaw_bin_deg);
  const double yaw_bin = 2.0 * M_PI / static_cast<double>(n_yaw);
  std::mt19937 rng(41);
  std::uniform_real_distribution<double> angle(-M_PI, M_PI), xy(-30.0, 30.0);
  auto pair = [&](double a, int i) {
    const double c = std::cos(a), s = std::sin(a);
    return pair_vote_stages::TrunkPair{3.0, c, s, std::atan2(s, c), {xy(rng), xy(rng)}, i, i + 1};
  };
  std::vector<pair_vote_stages::TrunkPair> pq, pc;
  for (int i = 0; i < 100; ++i) pq.push_back(pair(angle(rng), i));
  for (int i = 0; i < 100; ++i) pc.push_back(pair(angle(rng), i));
  const double beside[] = {-3e-5, -1e-5, -1e-12, 0.0, 1e-12, 1e-5, 3e-5};
  for (int k = 0; k < 700; ++k) {  // candidate direction = query's + edge (+ pi: turned vote)
    const auto& q = pq[static_cast<size_t>(k) % pq.size()];
    const double edge = static_cast<double>(k % n_yaw) * yaw_bin + beside[k % 7];
    pc.push_back(pair(std::atan2(q.sin_a, q.cos_a) + edge - (k % 2) * M_PI, 100 + k));
  }
  const auto acc = pair_vote_stages::accumulateVotes(pq, pc, params);
  std::map<std::tuple<int64_t, int64_t, int64_t>, std::array<double, 3>> ref;
  for (const auto& a : pq) {
    for (const auto& b : pc) {
      const double cy = b.cos_a * a.cos_a + b.sin_a * a.sin_a;
      const double sy = b.sin_a * a.cos_a - b.cos_a * a.sin_a;
      for (const double sign : {1.0, -1.0}) {
        const double c = sign * cy, s = sign * sy;
        const Eigen::Vector2d t(b.mid.x() - (c * a.mid.x() - s * a.mid.y()),
                                b.mid.y() - (s * a.mid.x() + c * a.mid.y()));
        double yaw = std::atan2(s, c);
        if (yaw < 0.0) yaw += 2.0 * M_PI;
        const int64_t iyaw = std::min<int64_t>(static_cast<int64_t>(yaw / yaw_bin), n_yaw - 1);
        auto& r = ref[{iyaw, static_cast<int64_t>(std::floor(t.x() / params.vote_xy_bin_m)),
                       static_cast<int64_t>(std::floor(t.y() / params.vote_xy_bin_m))}];
        r[0] += 1.0, r[1] += c, r[2] += s;
      }
    }
  }
  ASSERT_EQ(acc.bins.size(), ref.size());
  for (const auto& b : acc.bins) {
    const auto it = ref.find({b.iyaw, b.ix, b.iy});
    ASSERT_NE(it, ref.end()) << b.iyaw << " " << b.ix << " " << b.iy;
    EXPECT_EQ(b.count, it->second[0]);
    EXPECT_DOUBLE_EQ(b.cos_sum, it->second[1]);
    EXPECT_DOUBLE_EQ(b.sin_sum, it->second[2]);
  }
}

TEST(QueryIndex, AReusedVoteAccumulatorEqualsAFreshOne) {
  // votePoses keeps one accumulator per thread: filled again after a larger and after a smaller
  // pair of stands (left full and grown, or with room to spare), its bins, in order, and its
  // lookups are those of a fresh one.
  const MatcherParams params;
  const auto cases = test::overlappingPairs(3, 23);
  ASSERT_EQ(cases.size(), 3u);
  auto pairsOf = [&](const Descriptor& d) {
    return pair_vote_stages::trunkPairs(d, params.vote_max_pair_m);
  };
  pair_vote_stages::VoteAccumulator reused;
  std::vector<std::tuple<int64_t, int64_t, int64_t>> previous;
  size_t checked = 0;
  for (const size_t k : {size_t{0}, size_t{1}, size_t{2}, size_t{0}}) {
    const auto pq = pairsOf(cases[k].q), pc = pairsOf(cases[k].c);
    const pair_vote_stages::VoteAccumulator fresh =
        pair_vote_stages::accumulateVotes(pq, pc, params);
    pair_vote_stages::accumulateVotes(pq, pc, params, &reused);
    ASSERT_EQ(reused.bins.size(), fresh.bins.size());
    ASSERT_GT(fresh.bins.size(), 100u);
    for (size_t i = 0; i < fresh.bins.size(); ++i) {
      const pair_vote_stages::VoteBin &a = reused.bins[i], &b = fresh.bins[i];
      ASSERT_EQ(std::make_tuple(a.iyaw, a.ix, a.iy), std::make_tuple(b.iyaw, b.ix, b.iy));
      EXPECT_EQ(a.count, b.count);
      EXPECT_EQ(a.cos_sum, b.cos_sum);
      EXPECT_EQ(a.sin_sum, b.sin_sum);
      EXPECT_EQ(a.t_sum, b.t_sum);
      EXPECT_EQ(reused.find(a.iyaw, a.ix, a.iy), &a);
      EXPECT_EQ(reused.find(a.iyaw, a.ix + 100000, a.iy), nullptr);
    }
    for (const auto& [iyaw, ix, iy] : previous)  // no bin left over from the last fill
      EXPECT_EQ(reused.find(iyaw, ix, iy) == nullptr, fresh.find(iyaw, ix, iy) == nullptr);
    previous.clear();
    for (const auto& b : fresh.bins) previous.emplace_back(b.iyaw, b.ix, b.iy);
    ++checked;
  }
  EXPECT_EQ(checked, 4u);
}

/// matchTriangles as it was before the squared-distance bound: every trunk pair's hypot sorted.
std::vector<MatchTriangle> referenceMatchTriangles(const Descriptor& d, int k) {
  const int n = static_cast<int>(d.trunks.size());
  const int kk = std::min(k, n - 1);
  auto key = [](int a, int b, int c) {
    std::array<int, 3> t{a, b, c};
    std::sort(t.begin(), t.end());
    return t;
  };
  std::vector<std::array<int, 3>> keys, faces;
  for (const Triangle& t : d.triangles) faces.push_back(key(t.v[0], t.v[1], t.v[2]));
  keys = faces;
  for (int i = 0; i < n; ++i) {
    std::vector<std::pair<double, int>> nn;
    for (int j = 0; j < n; ++j) {
      if (j != i)
        nn.emplace_back(std::hypot(d.trunks[i].x - d.trunks[j].x, d.trunks[i].y - d.trunks[j].y),
                        j);
    }
    std::partial_sort(nn.begin(), nn.begin() + kk, nn.end());
    for (int a = 0; a < kk; ++a)
      for (int b = a + 1; b < kk; ++b) keys.push_back(key(i, nn[a].second, nn[b].second));
  }
  std::sort(faces.begin(), faces.end());
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  std::vector<MatchTriangle> out;
  for (const auto& t : keys) {
    const Triangle tri = makeCanonicalTriangle(d.trunks, t[0], t[1], t[2]);
    if (tri.len[2] <= 1e-3) continue;
    const double s = 0.5 * (tri.len[0] + tri.len[1] + tri.len[2]);
    const double area2 = s * (s - tri.len[0]) * (s - tri.len[1]) * (s - tri.len[2]);
    const bool face = std::binary_search(faces.begin(), faces.end(), t);
    if (!face && (area2 <= 0.0 || std::sqrt(area2) < 0.05 * tri.len[0] * tri.len[0])) continue;
    out.push_back({tri, face});
  }
  std::stable_sort(out.begin(), out.end(), [](const MatchTriangle& a, const MatchTriangle& b) {
    return a.t.len[0] < b.t.len[0];
  });
  return out;
}

TEST(QueryIndex, NeighbourTrianglesEqualTheFullDistanceSort) {
  // Random stands, and a perfect grid: there every trunk has four neighbours at exactly the same
  // distance, so ties decide which of them are the k nearest.
  std::vector<Descriptor> ds;
  for (const test::PairCase& pc : test::overlappingPairs(4, 19)) ds.push_back(pc.q);
  Trunks grid;
  for (int x = 0; x < 9; ++x)
    for (int y = 0; y < 9; ++y) grid.push_back({3.0 * x, 3.0 * y, 0.0, 0.12});
  ds.push_back(test::describe(grid, "grid", 0, 0.0));
  for (const Descriptor& d : ds) {
    ASSERT_TRUE(d.valid);
    for (int k : {1, 3, 4, 6}) {
      const std::vector<MatchTriangle> a = matchTriangles(d, k), b = referenceMatchTriangles(d, k);
      ASSERT_EQ(a.size(), b.size()) << "k " << k;
      for (size_t i = 0; i < a.size(); ++i) {
        EXPECT_EQ(a[i].t.v, b[i].t.v) << "k " << k << " triangle " << i;
        EXPECT_EQ(a[i].delaunay, b[i].delaunay);
      }
    }
  }
}

TEST(QueryIndex, ConsistencyBoundsDecideLikeTheEdgeAndRadiusTests) {
  // Each bound and the float just past it, and random values, against consistentEdges on a
  // triangle that differs from the query's in that one value only.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> len(0.2f, 30.0f), rad(0.0f, 0.6f), any(0.0f, 40.0f);
  MatcherParams p;
  size_t passed = 0, failed = 0;
  for (int n = 0; n < 2000; ++n) {
    MatchTriangle q;
    for (int a = 0; a < 3; ++a) q.t.len[a] = len(rng), q.t.r[a] = rad(rng);
    if (n % 7 == 0) q.t.r[n % 3] = 0.0f;  // a radius not measured
    const ConsistencyBounds b = consistencyBounds({q}, p).front();
    ASSERT_TRUE(b.exact);
    for (int j = 0; j < 6; ++j) {
      const float lo = b.lo[j], hi = b.hi[j];
      const float inf = std::numeric_limits<float>::infinity();
      for (float v : {lo, std::nextafter(lo, -inf), hi, std::nextafter(hi, inf), any(rng),
                      j < 3 ? q.t.len[j] : q.t.r[j - 3]}) {
        Triangle c = q.t;
        (j < 3 ? c.len[j] : c.r[j - 3]) = v;
        const int mask = matcher_stages::consistentEdges(q.t, c, p);
        // A length is consistent when its edge is; a radius when both edges it ends are.
        const int touched = j < 3 ? 1 << j : j == 3 ? 0b011 : j == 4 ? 0b110 : 0b101;
        const bool consistent = (mask & touched) == touched;
        EXPECT_EQ(consistent, v >= lo && v <= hi) << "value " << j << " " << v;
        (consistent ? passed : failed)++;
      }
    }
  }
  EXPECT_GT(passed, 10000u);
  EXPECT_GT(failed, 10000u);
}

/// Views of one stand: robot "a" along a row, robot "b" along a row 5 m off, 6 m apart.
std::vector<std::shared_ptr<const Descriptor>> standViews(const Trunks& world, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI);
  std::vector<std::shared_ptr<const Descriptor>> out;
  for (int k = 0; k < 12; ++k) {
    const bool a = k % 2 == 0;
    const Eigen::Vector2d centre(20.0 + 6.0 * (k / 2), a ? 30.0 : 35.0);
    const double heading = yaw(rng);
    const Pose T_w_s = test::poseXyYaw(centre.x() + 1.0, centre.y() - 2.0, 0.0, heading);
    out.push_back(std::make_shared<Descriptor>(
        test::describe(test::observe(rng, world, centre, T_w_s), a ? "a" : "b", k, 100.0 * k)));
  }
  return out;
}

TEST(QueryIndex, SupportFromBoundsEqualsTheDirectTests) {
  // accumulateSupport decides a pair from the query triangle's bounds (masks of a whole window
  // first, then only the pairs that give support) or, without exact bounds, by consistentEdges
  // pair by pair: the same counts, faces and neighbour triangles alike, in a natural stand and
  // a jittered plantation (windows of thousands of near-equal triangles).
  std::mt19937 rng(31);
  const std::vector<std::vector<std::shared_ptr<const Descriptor>>> stands{
      standViews(test::randomStand(rng, 100, 70, 600), 5),
      standViews(test::plantation(rng, 100, 70, 3.0, 0.15), 6)};
  MatcherParams p;
  size_t strong = 0, weak = 0, kept = 0;
  for (const auto& views : stands) {
    for (size_t i = 0; i + 1 < views.size(); ++i) {
      const Descriptor &q = *views[i], &c = *views[i + 1];
      const auto tq = matchTriangles(q, p.neighbour_triangles);
      const auto tc = matchTriangles(c, p.neighbour_triangles);
      const auto bounds = consistencyBounds(tq, p);
      auto direct = bounds;
      for (ConsistencyBounds& b : direct) b.exact = false;
      size_t pairs_a = 0, pairs_b = 0;
      const auto a = matcher_stages::accumulateSupport(tq, tc, q.trunks.size(), c.trunks.size(), p,
                                                       &pairs_a, &bounds);
      const auto b = matcher_stages::accumulateSupport(tq, tc, q.trunks.size(), c.trunks.size(), p,
                                                       &pairs_b, &direct);
      EXPECT_EQ(pairs_a, pairs_b);
      ASSERT_EQ(a.strong, b.strong);
      ASSERT_EQ(a.weak, b.weak);
      EXPECT_EQ(a.touched, b.touched);  // the same pairs, by index
      // touched lists exactly the non-zero entries, ascending.
      std::vector<uint32_t> nonzero;
      for (size_t k = 0; k < a.strong.size(); ++k)
        if (a.strong[k] > 0 || a.weak[k] > 0) nonzero.push_back(static_cast<uint32_t>(k));
      EXPECT_EQ(a.touched, nonzero);
      for (size_t k = 0; k < a.strong.size(); ++k) strong += a.strong[k] > 0, weak += a.weak[k] > 0;
      // The heaviest K (selected, then sorted) are the first K of all of them sorted.
      MatcherParams all = p;
      all.max_correspondences = 1 << 30;
      const auto every = matcher_stages::weightedCorrespondences(a, q, c, all);
      MatcherParams few = p;
      few.max_correspondences = 40;
      const auto top = matcher_stages::weightedCorrespondences(a, q, c, few);
      ASSERT_EQ(top.size(), std::min<size_t>(40, every.size()));
      for (size_t k = 0; k < top.size(); ++k) {
        EXPECT_EQ(top[k].iq, every[k].iq);
        EXPECT_EQ(top[k].ic, every[k].ic);
        EXPECT_EQ(top[k].w, every[k].w);
      }
      kept += every.size() > top.size();
    }
  }
  EXPECT_GT(strong, 1000u);  // the cases under test happened
  EXPECT_GT(weak, 1000u);
  EXPECT_GT(kept, 10u);
}

/// The loop query keeps: every candidate matched and verified in screening order (matchPair),
/// the highest score kept, the first of equal ones.
std::optional<Loop> bruteBestLoop(const LoopDetector& det, const Descriptor& q,
                                  const std::vector<int64_t>& candidates) {
  LoopDetectorParams no_votes = det.params();
  no_votes.matcher.vote_fallback = false;
  std::optional<Loop> best;
  for (size_t rank = 0; rank < candidates.size(); ++rank) {
    const auto it = std::find_if(det.entries().begin(), det.entries().end(),
                                 [&](const auto& d) { return d->submap_id == candidates[rank]; });
    const bool votes = rank < static_cast<size_t>(det.params().database.max_vote_candidates);
    auto lc = matchPair(q, **it, votes ? det.params() : no_votes);
    if (lc && (!best || lc->score > best->score)) best = std::move(lc);
  }
  return best;
}

TEST(QueryIndex, QueryKeepsTheBestScoringLoopOfItsCandidates) {
  std::mt19937 rng(23);
  // A natural stand and a jittered plantation (lattice searches), each seen from 12 places.
  std::vector<std::vector<std::shared_ptr<const Descriptor>>> stands{
      standViews(test::randomStand(rng, 100, 70, 600), 3),
      standViews(test::plantation(rng, 100, 70, 3.0, 0.15), 4)};
  LoopDetectorParams p;
  p.database.max_vote_candidates = 3;   // candidates past it are matched without the votes
  p.database.max_lattice_searches = 0;  // no limit: every candidate as if verified
  p.database.decisive_score = 0.0;      // every candidate matched
  size_t loops = 0, several = 0, unverified = 0;
  for (const auto& views : stands) {
    LoopDetector det(p);
    for (const auto& d : views) {
      QueryStats st;
      const std::optional<Loop> got = det.query(*d, &st);
      const std::optional<Loop> want = bruteBestLoop(det, *d, st.candidates);
      ASSERT_EQ(got.has_value(), want.has_value()) << d->robot << "/" << d->submap_id;
      if (got) {
        ++loops;
        EXPECT_EQ(got->candidate_id, want->candidate_id) << d->submap_id;
        EXPECT_EQ(got->score, want->score);
        EXPECT_EQ(got->T_c_q.matrix(), want->T_c_q.matrix());
        EXPECT_EQ(got->covariance, want->covariance);
        EXPECT_EQ(got->inlier_pairs, want->inlier_pairs);
        EXPECT_EQ(got->all_pairs, want->all_pairs);
      }
      several += st.verified > 1;
      unverified += st.unverified;
      det.insert(d);
    }
  }
  // The case under test happened: loops, queries with several accepted candidates, and
  // candidates left unverified.
  EXPECT_GE(loops, 12u);
  EXPECT_GT(several, 0u);
  EXPECT_GT(unverified, 0u);
}

TEST(QueryIndex, ADecisiveLoopEndsMatching) {
  // Two robots' views of a natural stand. A query that stops matching does so at a candidate
  // whose loop scores at least decisive_score (with another robot when an inter-robot loop is
  // asked for) and returns the best loop of the candidates matched so far; a query that does
  // not stop returns what matching every candidate returns.
  std::mt19937 rng(29);
  const auto views = standViews(test::randomStand(rng, 100, 70, 600), 5);
  for (const bool inter : {false, true}) {
    LoopDetectorParams decisive, every;
    decisive.database.decisive_score = 0.5;
    every.database.decisive_score = 0.0;  // every candidate matched
    LoopDetector det(decisive), det_every(every);
    size_t stopped = 0, went_on = 0;
    for (const auto& d : views) {
      QueryStats st, st_every;
      std::optional<Loop> beside, beside_every;
      const std::optional<Loop> got = det.query(*d, &st, inter ? &beside : nullptr);
      const std::optional<Loop> all =
          det_every.query(*d, &st_every, inter ? &beside_every : nullptr);
      EXPECT_EQ(st_every.hypothesized, st_every.candidates.size());
      if (st.hypothesized < st.candidates.size()) {
        ++stopped;
        const int64_t last_id = st.candidates[st.hypothesized - 1];
        const auto last = std::find_if(det.entries().begin(), det.entries().end(),
                                       [&](const auto& e) { return e->submap_id == last_id; });
        const std::optional<Loop> ended = matchPair(*d, **last, decisive);
        ASSERT_TRUE(ended.has_value()) << d->submap_id;
        EXPECT_GE(ended->score, 0.5);
        if (inter) {
          EXPECT_NE((*last)->robot, d->robot);
        }
        const std::vector<int64_t> matched(st.candidates.begin(),
                                           st.candidates.begin() + st.hypothesized);
        const std::optional<Loop> want = bruteBestLoop(det, *d, matched);
        ASSERT_TRUE(got.has_value() && want.has_value()) << d->submap_id;
        EXPECT_EQ(got->score, want->score);
        EXPECT_EQ(got->T_c_q.matrix(), want->T_c_q.matrix());
      } else {
        went_on += got.has_value();
        ASSERT_EQ(got.has_value(), all.has_value()) << d->submap_id;
        if (got) {
          EXPECT_EQ(got->candidate_id, all->candidate_id);
          EXPECT_EQ(got->score, all->score);
        }
        EXPECT_EQ(beside.has_value(), beside_every.has_value());
      }
      det.insert(d);
      det_every.insert(d);
    }
    // The cases under test happened: queries that stopped, and loops of queries that did not.
    EXPECT_GT(stopped, 0u) << "inter " << inter;
    EXPECT_GT(went_on, 0u) << "inter " << inter;
  }
}

TEST(QueryIndex, LatticeSearchIsNeededExactlyWhenVerificationSearches) {
  // needsLatticeSearch, which query's search budget counts by, against what verification did:
  // it reports a fit ambiguity only when it searched the lattice.
  std::mt19937 rng(41);
  const std::vector<std::vector<std::shared_ptr<const Descriptor>>> stands{
      standViews(test::randomStand(rng, 100, 70, 600), 7),
      standViews(test::plantation(rng, 100, 70, 3.0, 0.15), 8)};
  size_t searched = 0, not_searched = 0;
  for (const bool fit : {true, false}) {
    LoopDetectorParams p;
    if (!fit) p.verification.max_fit_ambiguity = 0.0;  // ambiguous: rejected, no search
    for (const auto& views : stands) {
      for (size_t i = 0; i + 1 < views.size(); ++i) {
        for (size_t j = i + 1; j < views.size(); j += 3) {
          PoseEstimate est;
          Verification ver;
          matchPair(*views[i], *views[j], p, &est, &ver);
          const bool needs = needsLatticeSearch(est, p.verification);
          EXPECT_EQ(needs, ver.fit_ambiguity >= 0.0) << i << " " << j << " " << ver.reason();
          (needs ? searched : not_searched) += 1;
        }
      }
    }
  }
  EXPECT_GT(searched, 5u);  // both cases happened
  EXPECT_GT(not_searched, 5u);
}

TEST(QueryIndex, LatticeSearchesStopAtTheBudget) {
  // A jittered plantation seen from 12 places: with a budget of one lattice search, a query
  // searches at most once; when it skipped none its loop is the unlimited query's, else the
  // loop it returns (if any) is a verified loop of that candidate, scoring no higher.
  std::mt19937 rng(43);
  const auto views = standViews(test::plantation(rng, 100, 70, 3.0, 0.15), 4);
  LoopDetectorParams one, free;
  one.database.max_lattice_searches = 1;
  free.database.max_lattice_searches = 0;
  LoopDetector det_one(one), det_free(free);
  size_t skipped = 0, several = 0, differs = 0;
  for (const auto& d : views) {
    QueryStats st, st_free;
    const std::optional<Loop> got = det_one.query(*d, &st);
    const std::optional<Loop> all = det_free.query(*d, &st_free);
    EXPECT_LE(st.lattice_searches, 1u);
    EXPECT_EQ(st_free.lattice_skipped, 0u);
    skipped += st.lattice_skipped;
    several += st_free.lattice_searches > 1;
    if (st.lattice_skipped == 0) {
      ASSERT_EQ(got.has_value(), all.has_value()) << d->submap_id;
      if (got) {
        EXPECT_EQ(got->candidate_id, all->candidate_id);
        EXPECT_EQ(got->score, all->score);
      }
    } else if (got) {
      ASSERT_TRUE(all.has_value()) << d->submap_id;
      EXPECT_LE(got->score, all->score);
      const auto it =
          std::find_if(det_one.entries().begin(), det_one.entries().end(),
                       [&](const auto& e) { return e->submap_id == got->candidate_id; });
      ASSERT_NE(it, det_one.entries().end());
      const std::optional<Loop> alone = matchPair(*d, **it, one);
      ASSERT_TRUE(alone.has_value());
      EXPECT_EQ(alone->score, got->score);
    }
    differs += got.has_value() != all.has_value() ||
               (got && all && got->candidate_id != all->candidate_id);
    det_one.insert(d);
    det_free.insert(d);
  }
  // The cases under test happened: queries that searched more than once without a limit,
  // and searches the budget skipped.
  EXPECT_GT(several, 0u);
  EXPECT_GT(skipped, 0u);
  RecordProperty("queries_with_another_loop", static_cast<int>(differs));
}

}  // namespace
}  // namespace dtif
