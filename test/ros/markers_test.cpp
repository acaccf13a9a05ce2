// RecentMarkers: the marker arrays the nodelets publish again for rviz, without a master.
#include "dtif/ros/markers.h"

#include <gtest/gtest.h>

namespace dtif {
namespace ros_glue {
namespace {

visualization_msgs::MarkerArray arrayOf(const std::string& ns, int n) {
  visualization_msgs::MarkerArray a;
  for (int i = 0; i < n; ++i) {
    visualization_msgs::Marker m;
    m.ns = ns;
    m.id = i;
    a.markers.push_back(m);
  }
  return a;
}

TEST(RecentMarkers, KeepsTheLatestArraysOldestFirst) {
  RecentMarkers r(2);
  EXPECT_FALSE(r.all());  // nothing to publish yet
  r.add(arrayOf("submap_0", 3));
  r.add(arrayOf("submap_1", 1));
  r.add(arrayOf("submap_2", 2));  // drops submap_0
  EXPECT_EQ(r.size(), 2u);
  const auto all = r.all();
  ASSERT_TRUE(all);
  ASSERT_EQ(all->markers.size(), 3u);
  EXPECT_EQ(all->markers[0].ns, "submap_1");
  EXPECT_EQ(all->markers[1].ns, "submap_2");
  EXPECT_EQ(all->markers[1].id, 0);
  EXPECT_EQ(all->markers[2].id, 1);
  // The returned array is a snapshot: later additions do not change it.
  r.add(arrayOf("submap_3", 5));
  EXPECT_EQ(all->markers.size(), 3u);
  EXPECT_EQ(r.all()->markers.size(), 7u);
}

TEST(RecentMarkers, CapacityZeroKeepsNothing) {
  RecentMarkers r(0);
  r.add(arrayOf("a", 1));
  EXPECT_EQ(r.size(), 0u);
  EXPECT_FALSE(r.all());
}

}  // namespace
}  // namespace ros_glue
}  // namespace dtif
