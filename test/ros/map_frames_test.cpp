#include "dtif/ros/map_frames.h"

#include <gtest/gtest.h>

namespace dtif::ros_glue {
namespace {

TEST(MapFrames, OneFramePerComponentLargestFirst) {
  MapFrames f;
  const auto changes = f.assign({{"c"}, {"a", "b"}});
  EXPECT_EQ(f.frameOf("a"), "map");
  EXPECT_EQ(f.frameOf("b"), "map");
  EXPECT_EQ(f.frameOf("c"), "map_1");
  ASSERT_EQ(changes.size(), 3u);
  EXPECT_EQ(changes[0].from, "");
  EXPECT_EQ(f.frameOf("nobody"), "");
}

TEST(MapFrames, FramesStayWhenAComponentGrowsPastAnother) {
  MapFrames f;
  f.assign({{"a", "b"}, {"c"}});
  // c's component grows larger than a's: neither robot changes frame.
  const auto changes = f.assign({{"a", "b"}, {"c", "d", "e"}});
  EXPECT_EQ(f.frameOf("a"), "map");
  EXPECT_EQ(f.frameOf("c"), "map_1");
  EXPECT_EQ(f.frameOf("d"), "map_1");
  ASSERT_EQ(changes.size(), 2u);  // only the new robots d and e
  EXPECT_EQ(changes[0].robot, "d");
}

TEST(MapFrames, JoiningComponentsTakeTheLowestFrameAndReportTheMove) {
  MapFrames f;
  f.assign({{"a"}, {"b"}, {"c"}});
  EXPECT_EQ(f.frameOf("c"), "map_2");
  const auto changes = f.assign({{"a"}, {"b", "c"}});
  EXPECT_EQ(f.frameOf("b"), "map_1");
  ASSERT_EQ(changes.size(), 1u);
  EXPECT_EQ(changes[0].robot, "c");
  EXPECT_EQ(changes[0].from, "map_2");
  EXPECT_EQ(changes[0].to, "map_1");
  // A split (a loop rejected later): the larger part keeps the frame, the other gets a free one.
  MapFrames g("m");
  g.assign({{"a", "b", "c"}});
  g.assign({{"c"}, {"a", "b"}});
  EXPECT_EQ(g.frameOf("a"), "m");
  EXPECT_EQ(g.frameOf("c"), "m_1");
}

}  // namespace
}  // namespace dtif::ros_glue
