#include "dtif/core/database/loop_detector.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <stdexcept>

#include "core/loop_test_utils.h"
#include "dtif/core/database/loop_pair.h"

namespace dtif {
namespace {

using test::describe;
using test::observe;
using test::overlappingPairs;
using test::PairCase;
using test::poseXyYaw;

TEST(LoopDetector, RecoversOverlappingPairsInRandomStands) {
  const LoopDetectorParams params;
  const std::vector<PairCase> cases = overlappingPairs(60, 2024);
  int accepted = 0;
  double sum_rot = 0, sum_t = 0, sum_z = 0, max_rot = 0, max_t = 0;
  for (const PairCase& pc : cases) {
    ASSERT_TRUE(pc.q.valid && pc.c.valid);
    PoseEstimate est;
    Verification ver;
    const auto lc = matchPair(pc.q, pc.c, params, &est, &ver);
    if (!lc) {
      std::printf("[ info ] rejected: %s (inliers %zu, rms %.3f, amb %.2f, cov %.2f)\n",
                  ver.reason().c_str(), est.inliers_T.size(), est.rms_xy_m, ver.ambiguity,
                  ver.covisible_ratio);
      continue;
    }
    ++accepted;
    const double rot = test::yawError(lc->T_c_q, pc.T_c_q) * 180.0 / M_PI;
    const Eigen::Vector3d dt = lc->T_c_q.translation() - pc.T_c_q.translation();
    // Every accepted loop must be right: a wrong one corrupts the merged map.
    EXPECT_LT(rot, 0.3);
    EXPECT_LT(dt.head<2>().norm(), 0.15);
    sum_rot += rot;
    sum_t += dt.head<2>().norm();
    sum_z += std::fabs(dt.z());
    max_rot = std::max(max_rot, rot);
    max_t = std::max(max_t, dt.head<2>().norm());
  }
  std::printf(
      "[ info ] accepted %d/%zu; mean rot %.3f deg (max %.3f), xy %.3f m (max %.3f), "
      "z %.3f m\n",
      accepted, cases.size(), sum_rot / accepted, max_rot, sum_t / accepted, max_t,
      sum_z / accepted);
  EXPECT_GE(accepted, static_cast<int>(0.9 * cases.size()));
  ASSERT_GT(accepted, 0);
  EXPECT_LT(sum_rot / accepted, 0.3);
  EXPECT_LT(sum_t / accepted, 0.15);
  EXPECT_LT(sum_z / accepted, 0.1);
}

TEST(LoopDetector, Exact180DegreesAndUtmScaleCoordinates) {
  std::mt19937 rng(180);
  const Trunks world = test::randomStand(rng, 80, 80, 600);
  const Pose T_w_c = poseXyYaw(312000.0, 5096000.0, 180.0, 0.0);
  const Pose T_w_q = poseXyYaw(-1e5, 1e5, -50.0, M_PI);
  const Descriptor c = describe(observe(rng, world, {40, 40}, T_w_c), "a", 0, 0.0);
  const Descriptor q = describe(observe(rng, world, {45, 38}, T_w_q), "b", 1, 0.0);
  Verification ver;
  const auto lc = matchPair(q, c, LoopDetectorParams{}, nullptr, &ver);
  ASSERT_TRUE(lc) << ver.reason();
  const Pose T_c_q = T_w_c.inverse() * T_w_q;
  EXPECT_LT(test::yawError(lc->T_c_q, T_c_q) * 180.0 / M_PI, 0.3);
  // Compare the effect on a point of the query submap, not the ~1e5 m raw translation.
  const Eigen::Vector3d p = T_w_q.inverse() * Eigen::Vector3d(45, 38, 0);
  EXPECT_LT((lc->T_c_q * p - T_c_q * p).head<2>().norm(), 0.15);
  EXPECT_LT(std::fabs((lc->T_c_q * p - T_c_q * p).z()), 0.1);
}

TEST(LoopDetector, RejectsDisjointPlacesOfRandomStands) {
  std::mt19937 rng(77);
  const LoopDetectorParams params;
  std::uniform_real_distribution<double> yaw(-M_PI, M_PI);
  int false_accepts = 0, tried = 0;
  for (int i = 0; i < 30; ++i) {
    const Trunks world = test::randomStand(rng, 200, 60, 400 + 13 * i);
    const Descriptor q =
        describe(observe(rng, world, {30, 30}, poseXyYaw(30, 30, 0, yaw(rng))), "a", 0, 0.0);
    const Descriptor c =
        describe(observe(rng, world, {30 + 35 + 3 * (i % 20), 30}, poseXyYaw(90, 30, 0, yaw(rng))),
                 "b", 1, 0.0);
    ++tried;
    if (matchPair(q, c, params)) ++false_accepts;
  }
  EXPECT_EQ(false_accepts, 0) << "of " << tried;
}

TEST(LoopDetector, DatabaseQueryFindsTheOverlappingSubmap) {
  const std::vector<PairCase> cases = overlappingPairs(20, 555);
  LoopDetector db{LoopDetectorParams{}};
  for (const PairCase& pc : cases) {
    EXPECT_TRUE(db.insert(std::make_shared<Descriptor>(pc.c)));
  }
  EXPECT_FALSE(db.insert(std::make_shared<Descriptor>())) << "invalid must be refused";
  EXPECT_EQ(db.size(), cases.size());
  int found = 0;
  for (size_t i = 0; i < cases.size(); ++i) {
    QueryStats st;
    const auto lc = db.query(cases[i].q, &st);
    EXPECT_EQ(st.eligible, cases.size());
    if (!lc) {
      MatchStats ms;
      buildCorrespondences(cases[i].q, cases[i].c, MatcherParams{}, &ms);
      Verification ver;
      const bool direct =
          matchPair(cases[i].q, cases[i].c, LoopDetectorParams{}, nullptr, &ver).has_value();
      std::printf("[ info ] query %zu: no loop (s_e %.2f, s_r %.2f, direct match %d: %s)\n", i,
                  ms.edge_hist_sim, ms.radius_hist_sim, direct, ver.reason().c_str());
      continue;
    }
    // The only true loop of query i is candidate i (the other stands are unrelated).
    EXPECT_EQ(lc->candidate_id, cases[i].c.submap_id);
    EXPECT_EQ(lc->query_id, cases[i].q.submap_id);
    if (lc->candidate_id != cases[i].c.submap_id) continue;
    ++found;
    EXPECT_LT(test::yawError(lc->T_c_q, cases[i].T_c_q), 0.3 * M_PI / 180.0);
    EXPECT_GE(lc->inliers, LoopDetectorParams{}.verification.min_inliers);
    // Every inlier pair is a true correspondence: under the true pose the query trunk lands on
    // its candidate trunk. The stand's stems are >= 1 m apart and each side adds 3 cm of noise
    // per axis, so a true pair is within 0.25 m (6 sigma) and a pair of different stems is not.
    ASSERT_FALSE(lc->inlier_pairs.empty());
    for (const auto& [iq, ic] : lc->inlier_pairs) {
      const TrunkLandmark& tq = cases[i].q.trunks.at(iq);
      const TrunkLandmark& tc = cases[i].c.trunks.at(ic);
      const Eigen::Vector3d p = cases[i].T_c_q * Eigen::Vector3d(tq.x, tq.y, tq.z);
      EXPECT_LT(std::hypot(p.x() - tc.x, p.y() - tc.y), 0.25)
          << "query " << i << " pair (" << iq << ", " << ic << ")";
    }
    EXPECT_GT(lc->covariance(0, 0), 0.0);
    EXPECT_GT(lc->score, 0.0);
    EXPECT_LE(lc->score, 1.0);
  }
  // Measured: 17 of 20 (the 3 misses have < 4 descriptor inliers: sparse stands, large
  // offsets). Pair-level recall >= 0.9 is asserted on 60 pairs above.
  EXPECT_GE(found, 17);
}

TEST(LoopDetector, ReplaceSwapsAnEntryInPlace) {
  // Entry "a"/0 first holds stand 0, then (forward accumulation) stand 1's trunks: queries of
  // stand 1 find it, queries of stand 0 no longer do; its odometry and position stay.
  const std::vector<PairCase> cases = overlappingPairs(2, 77);
  LoopDetector db{LoopDetectorParams{}};
  EntryOdometry odom;
  odom.odom_frame = "a/odom";
  odom.T_O_S = poseXyYaw(1, 2, 0, 0.3);
  ASSERT_TRUE(db.insert(std::make_shared<Descriptor>(cases[0].c), odom));
  Descriptor other = cases[1].c;
  other.robot = "c";
  ASSERT_TRUE(db.insert(std::make_shared<Descriptor>(other)));
  ASSERT_TRUE(db.query(cases[0].q).has_value());
  const size_t triangles_before = db.matchTrianglesOf(0).size();

  Descriptor updated = cases[1].c;  // stand 1's trunks under entry 0's identity
  updated.robot = cases[0].c.robot;
  updated.submap_id = cases[0].c.submap_id;
  EXPECT_TRUE(db.replace(std::make_shared<Descriptor>(updated)));
  EXPECT_EQ(db.size(), 2u);
  EXPECT_EQ(db.entries()[0]->trunks.size(), updated.trunks.size());
  EXPECT_EQ(db.odometry(0).odom_frame, "a/odom");
  EXPECT_NE(db.matchTrianglesOf(0).size(), triangles_before);
  EXPECT_EQ(db.matchTrianglesOf(0).size(),
            matchTriangles(updated, MatcherParams{}.neighbour_triangles).size());
  const auto lc = db.query(cases[1].q);
  ASSERT_TRUE(lc.has_value());
  EXPECT_LT(test::yawError(lc->T_c_q, cases[1].T_c_q), 0.3 * M_PI / 180.0);
  const auto old = db.query(cases[0].q);
  EXPECT_FALSE(old.has_value() && old->candidate_robot == "a");

  Descriptor unknown = updated;
  unknown.submap_id = 999;  // no such entry
  EXPECT_FALSE(db.replace(std::make_shared<Descriptor>(unknown)));
  EXPECT_FALSE(db.replace(std::make_shared<Descriptor>()));  // invalid
  EXPECT_FALSE(db.replace(nullptr));
  EXPECT_EQ(db.entries()[0]->trunks.size(), updated.trunks.size());
}

TEST(LoopDetector, ExcludesRecentSubmapsOfTheSameRobot) {
  const std::vector<PairCase> cases = overlappingPairs(1, 31);
  LoopDetectorParams p;
  p.database.exclude_recent_s = 30.0;
  LoopDetector db(p);
  Descriptor c = cases[0].c, q = cases[0].q;
  c.robot = q.robot = "r";
  c.stamp = 100.0;
  q.stamp = 110.0;
  db.insert(std::make_shared<Descriptor>(c));
  QueryStats st;
  EXPECT_FALSE(db.query(q, &st).has_value());
  EXPECT_EQ(st.eligible, 0u);
  q.stamp = 200.0;  // an old revisit of the same robot is a loop
  EXPECT_TRUE(db.query(q, &st).has_value());
  EXPECT_EQ(st.eligible, 1u);
}

TEST(LoopDetector, SaveLoadRoundTripAndCorruptFileLeavesDbUnchanged) {
  const std::vector<PairCase> cases = overlappingPairs(5, 8);
  LoopDetector db{LoopDetectorParams{}};
  for (const PairCase& pc : cases) db.insert(std::make_shared<Descriptor>(pc.c));
  const std::string path = ::testing::TempDir() + "/dtif_db_test.bin";
  db.save(path);

  LoopDetector other{LoopDetectorParams{}};
  other.load(path);
  ASSERT_EQ(other.size(), db.size());
  for (size_t i = 0; i < db.size(); ++i) {
    EXPECT_EQ(other.entries()[i]->submap_id, db.entries()[i]->submap_id);
    EXPECT_EQ(other.entries()[i]->robot, db.entries()[i]->robot);
    EXPECT_EQ(other.entries()[i]->triangles.size(), db.entries()[i]->triangles.size());
  }
  // Loaded database answers like the original.
  const auto a = db.query(cases[2].q), b = other.query(cases[2].q);
  ASSERT_TRUE(a && b);
  EXPECT_EQ(a->candidate_id, b->candidate_id);
  EXPECT_LT((a->T_c_q.translation() - b->T_c_q.translation()).norm(), 0.01);

  // Corrupt copies: flipped byte, truncation, wrong version, missing file.
  std::ifstream in(path, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto writeFile = [](const std::string& p, const std::vector<char>& b) {
    std::ofstream f(p, std::ios::binary | std::ios::trunc);
    f.write(b.data(), static_cast<std::streamsize>(b.size()));
  };
  LoopDetector small{LoopDetectorParams{}};
  small.insert(std::make_shared<Descriptor>(cases[0].c));
  const std::string bad = ::testing::TempDir() + "/dtif_db_bad.bin";
  std::vector<char> flipped = bytes;
  flipped[bytes.size() / 2] ^= 0x5a;
  std::vector<char> truncated(bytes.begin(), bytes.begin() + bytes.size() - 100);
  std::vector<char> version = bytes;
  version[8] = 7;
  for (const auto& b : {flipped, truncated, version}) {
    writeFile(bad, b);
    try {
      small.load(bad);
      ADD_FAILURE() << "corrupt file accepted";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
    }
    ASSERT_EQ(small.size(), 1u);
    EXPECT_EQ(small.entries()[0]->submap_id, cases[0].c.submap_id);
  }
  EXPECT_THROW(small.load(bad + ".missing"), std::runtime_error);
  EXPECT_EQ(small.size(), 1u);
}

TEST(LoopDetector, ParamsValidate) {
  EXPECT_EQ(LoopDetectorParams{}.validate(), "");
  LoopDetectorParams p;
  p.verification.min_covisible_ratio = 1.5;
  EXPECT_NE(p.validate(), "");
  EXPECT_THROW(LoopDetector{p}, std::invalid_argument);
  p = LoopDetectorParams{};
  p.database.max_candidates = 0;
  EXPECT_NE(p.validate(), "");
  p = LoopDetectorParams{};
  p.matcher.alpha_w = 2.0;  // alpha_s > alpha_w required by Eq. (3.9)
  EXPECT_NE(p.validate(), "");
  p = LoopDetectorParams{};
  p.pose.gnc_factor = 1.0;
  EXPECT_NE(p.validate(), "");
  p = LoopDetectorParams{};
  p.database.max_lattice_searches = -1;
  EXPECT_NE(p.validate().find("max_lattice_searches"), std::string::npos);
  p.database.max_lattice_searches = 0;  // no limit
  EXPECT_EQ(p.validate(), "");
  p.verification.lattice_refined_poses = -1;
  EXPECT_NE(p.validate().find("lattice_refined_poses"), std::string::npos);
  p.verification.lattice_refined_poses = 0;  // every pose by the finer fit
  EXPECT_EQ(p.validate(), "");
}

/// Two correspondences at most: the triangles give no hypothesis ("few correspondences"). With
/// the vote fallback the voted trunk pairs become the correspondences and find the loops; a
/// pair it cannot find keeps both reasons.
TEST(LoopDetector, NoHypothesisTriggersTheVoteFallback) {
  LoopDetectorParams with, without;
  with.matcher.max_correspondences = without.matcher.max_correspondences = 2;
  without.matcher.vote_fallback = false;
  ASSERT_TRUE(with.matcher.vote_fallback);
  ASSERT_EQ(with.validate(), "");
  const std::vector<PairCase> cases = overlappingPairs(10, 2024);
  int found = 0;
  for (const PairCase& pc : cases) {
    Verification ver;
    EXPECT_FALSE(matchPair(pc.q, pc.c, without, nullptr, &ver).has_value());
    EXPECT_EQ(ver.rejection, Rejection::kFewCorrespondences);
    EXPECT_EQ(ver.vote_rejection, Rejection::kNone);
    EXPECT_EQ(ver.reason(), "few correspondences");

    const auto lc = matchPair(pc.q, pc.c, with, nullptr, &ver);
    if (!lc) {
      EXPECT_EQ(ver.rejection, Rejection::kFewCorrespondences);
      EXPECT_NE(ver.vote_rejection, Rejection::kNone);
      EXPECT_EQ(ver.reason().rfind("few correspondences; votes: ", 0), 0u) << ver.reason();
      continue;
    }
    ++found;
    EXPECT_EQ(ver.rejection, Rejection::kNone);
    EXPECT_GT(lc->all_pairs.size(), 2u);  // the voted pairs, not the two correspondences
    EXPECT_LT(test::yawError(lc->T_c_q, pc.T_c_q) * 180.0 / M_PI, 0.3);
    EXPECT_LT((lc->T_c_q.translation() - pc.T_c_q.translation()).head<2>().norm(), 0.15);
  }
  EXPECT_GE(found, 8);
}

/// The vote fallback runs only when the triangles gave fewer than vote_max_correspondences
/// correspondences: with two at most (max_correspondences 2), a cap of 2 leaves every pair with
/// the triangles' rejection alone (no votes, no loop), a cap of 3 or none votes as before.
TEST(LoopDetector, TheVoteFallbackStopsAtVoteMaxCorrespondences) {
  LoopDetectorParams votes, capped, above;
  votes.matcher.max_correspondences = 2;
  votes.matcher.vote_max_correspondences = 0;  // no limit
  capped = above = votes;
  capped.matcher.vote_max_correspondences = 2;
  above.matcher.vote_max_correspondences = 3;
  ASSERT_EQ(capped.validate(), "");
  int at_cap = 0, found = 0;
  for (const PairCase& pc : overlappingPairs(10, 2024)) {
    if (buildCorrespondences(pc.q, pc.c, votes.matcher).size() != 2) continue;
    ++at_cap;
    Verification ver, ver_above;
    EXPECT_FALSE(matchPair(pc.q, pc.c, capped, nullptr, &ver).has_value());
    EXPECT_EQ(ver.rejection, Rejection::kFewCorrespondences);
    EXPECT_EQ(ver.vote_rejection, Rejection::kNone);  // no votes
    const auto lc = matchPair(pc.q, pc.c, votes, nullptr, &ver);
    const auto lc_above = matchPair(pc.q, pc.c, above, nullptr, &ver_above);
    EXPECT_EQ(lc.has_value(), lc_above.has_value());
    EXPECT_EQ(ver.reason(), ver_above.reason());
    found += lc.has_value();
  }
  EXPECT_GE(at_cap, 8);
  EXPECT_GE(found, 6);  // the votes find loops that the capped fallback leaves
  capped.matcher.vote_max_correspondences = -1;
  EXPECT_NE(capped.validate().find("vote_max_correspondences"), std::string::npos);
}

/// The one "same robot, too recent" rule (query, evaluation, simulator, benchmark).
TEST(LoopDetector, EligibleLoopPairRule) {
  const std::string a = "a", b = "b";
  EXPECT_TRUE(eligibleLoopPair(a, 100.0, b, 100.0, 30.0));  // other robot, any time
  EXPECT_FALSE(eligibleLoopPair(a, 100.0, a, 80.0, 30.0));
  EXPECT_FALSE(eligibleLoopPair(a, 80.0, a, 100.0, 30.0));  // either order
  EXPECT_TRUE(eligibleLoopPair(a, 130.0, a, 100.0, 30.0));  // exactly the window: eligible
  EXPECT_TRUE(eligibleLoopPair(a, 70.0, a, 100.0, 30.0));
  EXPECT_FALSE(eligibleLoopPair(a, 129.9, a, 100.0, 30.0));
  EXPECT_TRUE(eligibleLoopPair(a, 100.0, a, 100.0, 0.0));   // no window
  EXPECT_TRUE(eligibleLoopPair(0, 100.0, 1, 100.0, 30.0));  // the simulator's robot indices
  EXPECT_FALSE(eligibleLoopPair(1, 100.0, 1, 110.0, 30.0));
}

/// The query also never matches a submap with itself, even without a time window.
TEST(LoopDetector, QueryNeverMatchesItsOwnSubmap) {
  const std::vector<PairCase> cases = overlappingPairs(1, 31);
  LoopDetectorParams p;
  p.database.exclude_recent_s = 0.0;
  LoopDetector db(p);
  Descriptor c = cases[0].c;
  db.insert(std::make_shared<Descriptor>(c));
  QueryStats st;
  EXPECT_FALSE(db.query(c, &st).has_value());
  EXPECT_EQ(st.eligible, 0u);
  Descriptor q = cases[0].q;
  q.robot = c.robot;
  q.stamp = c.stamp;  // same robot and time, another submap: eligible without a window
  EXPECT_TRUE(db.query(q, &st).has_value());
  EXPECT_EQ(st.eligible, 1u);
}

/// A place robot a saw twice and robot b once, farther off: a's revisit scores best against a's
/// own earlier submap; the inter-robot loop beside it is b's.
TEST(LoopDetector, ReportsTheInterRobotLoopBesideAnOwnRobotBestLoop) {
  std::mt19937 rng(4242);
  const Trunks world = test::randomStand(rng, 100, 100, 600);
  const Eigen::Vector2d centre(50, 50);
  const Pose T_w_q = poseXyYaw(50, 50, 0, 0.3), T_w_own = poseXyYaw(51, 50.5, 0, -1.0),
             T_w_b = poseXyYaw(61, 44, 0, 2.0);
  const Descriptor q = describe(observe(rng, world, centre, T_w_q), "a", 2, 200.0);
  const Descriptor own = describe(observe(rng, world, {51, 50.5}, T_w_own), "a", 0, 0.0);
  const Descriptor other = describe(observe(rng, world, {61, 44}, T_w_b), "b", 1, 100.0);
  const auto own_alone = matchPair(q, own, LoopDetectorParams{});
  const auto other_alone = matchPair(q, other, LoopDetectorParams{});
  ASSERT_TRUE(own_alone && other_alone);
  ASSERT_GT(own_alone->score, other_alone->score);  // the closer revisit scores better

  for (const bool on : {true, false}) {
    LoopDetectorParams p;
    p.database.inter_robot_verifications = on ? 1 : 0;
    LoopDetector db(p);
    db.insert(std::make_shared<Descriptor>(own));
    db.insert(std::make_shared<Descriptor>(other));
    const auto best_only = db.query(q);
    std::optional<Loop> inter;
    QueryStats st;
    const auto best = db.query(q, &st, &inter);
    // The best loop is the same with or without the inter-robot one.
    ASSERT_TRUE(best && best_only);
    EXPECT_EQ(best->candidate_robot, "a");
    EXPECT_EQ(best->candidate_id, best_only->candidate_id);
    EXPECT_TRUE(best->T_c_q.isApprox(best_only->T_c_q, 0.0));
    EXPECT_EQ(best->score, best_only->score);
    if (!on) {
      EXPECT_FALSE(inter);
      continue;
    }
    ASSERT_TRUE(inter);
    EXPECT_EQ(inter->candidate_robot, "b");
    EXPECT_EQ(inter->candidate_id, 1);
    EXPECT_EQ(inter->score, other_alone->score);
    const Pose T_b_q = T_w_b.inverse() * T_w_q;
    EXPECT_LT(test::yawError(inter->T_c_q, T_b_q), 0.3 * M_PI / 180.0);
    EXPECT_LT((inter->T_c_q.translation() - T_b_q.translation()).head<2>().norm(), 0.15);
    // b's hypothesis bound is below a's score: verified only to find the inter-robot loop.
    EXPECT_EQ(st.inter_robot_verified, 1u) << own_alone->score << " " << other_alone->score;
  }

  // A best loop with another robot already joins the robots: nothing beside it.
  LoopDetector db{LoopDetectorParams{}};
  db.insert(std::make_shared<Descriptor>(other));
  Descriptor q_c = q;
  q_c.robot = "c";
  std::optional<Loop> inter;
  ASSERT_TRUE(db.query(q_c, nullptr, &inter));
  EXPECT_FALSE(inter);
}

}  // namespace
}  // namespace dtif
