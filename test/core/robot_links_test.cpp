#include "dtif/core/database/robot_links.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "test_utils.h"

namespace dtif {
namespace {

using test::makePose;

// Edges as "parent>child" strings, in the tree's order.
std::vector<std::string> names(const std::vector<RobotLinks::Edge>& tree) {
  std::vector<std::string> out;
  for (const RobotLinks::Edge& e : tree) out.push_back(e.parent + ">" + e.child);
  return out;
}

const Pose kTab = makePose(10.0, -2.0, 0.5, 0.01, -0.02, 0.7);
const Pose kTbc = makePose(-3.0, 4.0, 0.1, 0.0, 0.0, -1.2);
const Pose kTcd = makePose(1.0, 1.0, -0.3, 0.02, 0.0, 2.9);
const Pose kTca = makePose(7.0, 6.0, 0.0, 0.0, 0.0, 0.3);

TEST(RobotLinks, EmptyAndSelfLinks) {
  RobotLinks links;
  EXPECT_TRUE(links.empty());
  EXPECT_TRUE(links.spanningTree().empty());
  links.add("a/odom", "a/odom", kTab);  // a frame is not linked to itself
  EXPECT_TRUE(links.empty());
  EXPECT_TRUE(links.spanningTree().empty());
}

TEST(RobotLinks, RootIsTheFrameThatSortsFirst) {
  RobotLinks links;
  links.add("bravo/odom", "alpha/odom", kTab);  // T_bravo_alpha
  EXPECT_EQ(links.size(), 1u);
  const std::vector<RobotLinks::Edge> tree = links.spanningTree();
  ASSERT_EQ(names(tree), (std::vector<std::string>{"alpha/odom>bravo/odom"}));
  EXPECT_TRUE(tree[0].T_parent_child.isApprox(kTab.inverse(), 1e-12));
}

TEST(RobotLinks, TwoComponentsHangFromTheirOwnRoots) {
  RobotLinks links;
  links.add("d", "c", kTcd);
  links.add("a", "b", kTab);
  const std::vector<RobotLinks::Edge> tree = links.spanningTree();
  ASSERT_EQ(names(tree), (std::vector<std::string>{"a>b", "c>d"}));
  EXPECT_EQ(tree[0].T_parent_child.matrix(), kTab.matrix());
  EXPECT_TRUE(tree[1].T_parent_child.isApprox(kTcd.inverse(), 1e-12));
}

TEST(RobotLinks, CycleKeepsTheFirstLinksBreadthFirst) {
  RobotLinks links;
  links.add("a", "b", kTab);
  links.add("b", "c", kTbc);
  links.add("c", "a", kTca);  // closes the cycle: a reaches c through it directly
  EXPECT_EQ(links.size(), 3u);
  const std::vector<RobotLinks::Edge> tree = links.spanningTree();
  ASSERT_EQ(names(tree), (std::vector<std::string>{"a>b", "a>c"}));
  EXPECT_EQ(tree[0].T_parent_child.matrix(), kTab.matrix());
  EXPECT_TRUE(tree[1].T_parent_child.isApprox(kTca.inverse(), 1e-12));
}

TEST(RobotLinks, ChainIsWalkedFromTheRootWhateverTheOrderOfAdding) {
  RobotLinks first, second;
  first.add("a", "b", kTab);
  first.add("b", "c", kTbc);
  first.add("c", "d", kTcd);
  second.add("c", "d", kTcd);
  second.add("b", "c", kTbc);
  second.add("a", "b", kTab);
  const std::vector<RobotLinks::Edge> tree = first.spanningTree();
  ASSERT_EQ(names(tree), (std::vector<std::string>{"a>b", "b>c", "c>d"}));
  const std::vector<RobotLinks::Edge> again = second.spanningTree();
  ASSERT_EQ(names(again), names(tree));
  for (size_t i = 0; i < tree.size(); ++i) {
    EXPECT_EQ(again[i].T_parent_child.matrix(), tree[i].T_parent_child.matrix());
  }
  // Parents precede children, so composing along the list reaches every frame from the root.
  const Pose T_a_d = tree[0].T_parent_child * tree[1].T_parent_child * tree[2].T_parent_child;
  EXPECT_TRUE(T_a_d.isApprox(kTab * kTbc * kTcd, 1e-12));
}

TEST(RobotLinks, RelinkingReplacesTheOldEdgeInEitherDirection) {
  RobotLinks links;
  links.add("a", "b", kTab);
  links.add("b", "a", kTbc);  // a newer estimate, given as T_b_a
  EXPECT_EQ(links.size(), 1u);
  std::vector<RobotLinks::Edge> tree = links.spanningTree();
  ASSERT_EQ(names(tree), (std::vector<std::string>{"a>b"}));
  EXPECT_TRUE(tree[0].T_parent_child.isApprox(kTbc.inverse(), 1e-12));
  links.add("a", "b", kTcd);  // and back again
  EXPECT_EQ(links.size(), 1u);
  tree = links.spanningTree();
  ASSERT_EQ(tree.size(), 1u);
  EXPECT_EQ(tree[0].T_parent_child.matrix(), kTcd.matrix());
}

}  // namespace
}  // namespace dtif
