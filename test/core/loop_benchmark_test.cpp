// Benchmark of the loop detector against a database of 1,000 synthetic submaps. Prints the
// descriptor build time, the query time (with its breakdown), the encoded size; asserts only
// correctness (every returned loop is a true one, with the right pose), never a timing.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <random>

#include "core/match_test_utils.h"
#include "dtif/core/database/loop_detector.h"

namespace dtif {
namespace {

using Clock = std::chrono::steady_clock;
double ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

struct Truth {
  int stand;
  Pose T_w_s;
};

TEST(LoopBenchmark, ThousandSubmapDatabase) {
  constexpr int kStands = 10, kPerStand = 100, kQueries = 40;
  std::mt19937 rng(4242);
  std::uniform_real_distribution<double> dens(400, 800), pos(20, 180), yaw(-M_PI, M_PI);
  std::vector<Trunks> stands;
  for (int s = 0; s < kStands; ++s) stands.push_back(test::randomStand(rng, 200, 200, dens(rng)));

  LoopDetector db{LoopDetectorParams{}};
  std::vector<Truth> truth;
  double build_ms = 0.0, bytes = 0.0;
  size_t trunks = 0;
  for (int s = 0; s < kStands; ++s) {
    for (int i = 0; i < kPerStand; ++i) {
      const double cy = pos(rng);  // drawn before x, as gcc did: the same data for any compiler
      const Eigen::Vector2d c(pos(rng), cy);
      const Pose T = test::poseXyYaw(c.x(), c.y(), 0, yaw(rng));
      const Trunks obs = test::observe(rng, stands[s], c, T);
      const auto t0 = Clock::now();
      auto d = std::make_shared<Descriptor>(buildDescriptor(obs, DescriptorParams{}));
      build_ms += ms(t0, Clock::now());
      d->robot = "a";
      d->submap_id = static_cast<int64_t>(truth.size());
      d->stamp = static_cast<double>(truth.size());
      bytes += static_cast<double>(encodeDescriptor(*d).size());
      trunks += d->trunks.size();
      truth.push_back({s, T});
      db.insert(d);
    }
  }
  const double n_db = static_cast<double>(truth.size());
  std::printf("[ info ] descriptor: %.2f ms mean build, %.0f bytes mean encoded, %.1f trunks\n",
              build_ms / n_db, bytes / n_db, trunks / n_db);
  ASSERT_GE(db.size(), 990u);

  int found = 0, wrong = 0, possible = 0;
  QueryStats sum;
  double total_ms = 0.0;
  for (int k = 0; k < kQueries; ++k) {
    const int s = k % kStands;
    const double cy = pos(rng);  // drawn before x, as gcc did: the same data for any compiler
    const Eigen::Vector2d c(pos(rng), cy);
    const Pose T_w_q = test::poseXyYaw(c.x(), c.y(), 0, yaw(rng));
    Descriptor q = buildDescriptor(test::observe(rng, stands[s], c, T_w_q), DescriptorParams{});
    q.robot = "b";
    q.submap_id = 100000 + k;
    // A true loop exists when a database submap of this stand is centred within 8 m.
    bool has_loop = false;
    for (const Truth& t : truth) {
      has_loop |= t.stand == s && (t.T_w_s.translation().head<2>() - c).norm() < 8.0;
    }
    possible += has_loop;
    QueryStats st;
    const auto t0 = Clock::now();
    const auto lc = db.query(q, &st);
    total_ms += ms(t0, Clock::now());
    sum.screen_ms += st.screen_ms;
    sum.match_ms += st.match_ms;
    sum.solver_ms += st.solver_ms;
    sum.verify_ms += st.verify_ms;
    sum.matched += st.matched;
    if (!lc) continue;
    const Truth& t = truth[lc->candidate_id];
    const Pose T_c_q = t.T_w_s.inverse() * T_w_q;
    const bool right = t.stand == s && test::yawError(lc->T_c_q, T_c_q) < 0.3 * M_PI / 180.0 &&
                       (lc->T_c_q.translation() - T_c_q.translation()).head<2>().norm() < 0.15;
    EXPECT_TRUE(right) << "query " << k << " -> " << lc->candidate_id;
    found += right;
    wrong += !right;
  }
  std::printf(
      "[ info ] query vs %zu submaps: %.2f ms mean (screen %.2f, match %.2f, solver %.2f,"
      " verify %.2f), %.1f candidates matched\n",
      db.size(), total_ms / kQueries, sum.screen_ms / kQueries, sum.match_ms / kQueries,
      sum.solver_ms / kQueries, sum.verify_ms / kQueries,
      static_cast<double>(sum.matched) / kQueries);
  std::printf("[ info ] loops: %d found, %d wrong, %d queries with a submap within 8 m\n", found,
              wrong, possible);
  EXPECT_EQ(wrong, 0);
  EXPECT_GE(found, possible * 8 / 10);
}

}  // namespace
}  // namespace dtif
