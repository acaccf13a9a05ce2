// The nodelets' callback-to-worker queue (ros_glue::BoundedQueue): order, the oldest item dropped
// when full, and close() waking a worker that waits.
#include "dtif/ros/bounded_queue.h"

#include <gtest/gtest.h>

#include <thread>
#include <vector>

namespace dtif::ros_glue {
namespace {

TEST(BoundedQueue, KeepsOrderAndDropsTheOldestWhenFull) {
  BoundedQueue<int> q(2);
  EXPECT_FALSE(q.push(1));
  EXPECT_FALSE(q.push(2));
  const std::optional<int> dropped = q.push(3);
  ASSERT_TRUE(dropped);
  EXPECT_EQ(*dropped, 1);
  EXPECT_EQ(q.size(), 2u);
  EXPECT_EQ(q.pop(), 2);
  EXPECT_EQ(q.pop(), 3);
  q.setCapacity(0);  // at least one item always fits
  EXPECT_FALSE(q.push(4));
  EXPECT_EQ(q.push(5), 4);
}

TEST(BoundedQueue, CloseEndsAWorkerThatWaitsAndHandsOutNothingMore) {
  BoundedQueue<int> q(8);
  std::vector<int> seen;
  std::thread worker([&] {
    while (std::optional<int> item = q.pop()) seen.push_back(*item);
  });
  for (int k = 0; k < 5; ++k) q.push(k);
  while (q.size() > 0) std::this_thread::yield();  // the worker took them all
  q.close();
  worker.join();  // returns: pop() woke up empty
  // It may still be processing the last one when size() reads 0, but it saw each once, in order.
  EXPECT_EQ(seen, (std::vector<int>{0, 1, 2, 3, 4}));
  q.push(9);
  EXPECT_FALSE(q.pop());  // closed: nothing more is handed out
}

}  // namespace
}  // namespace dtif::ros_glue
