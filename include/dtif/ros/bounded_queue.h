// The nodelets' hand-over from subscriber callbacks to their worker thread: callbacks push and
// return at once, the worker pops and does the heavy work. Bounded: a worker that falls behind
// loses the oldest item, never the callbacks' time. ROS-free so that it is tested without a
// master.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <optional>
#include <utility>

namespace dtif {
namespace ros_glue {

/// Thread-safety: every member may be called from any thread. Lifetime: close() before the
/// worker that pops is joined (the owner's destructor).
template <class T>
class BoundedQueue {
 public:
  /// At most `capacity` items wait (at least one).
  explicit BoundedQueue(size_t capacity = 1) : capacity_(capacity < 1 ? 1 : capacity) {}

  void setCapacity(size_t capacity) {
    std::lock_guard<std::mutex> lock(mutex_);
    capacity_ = capacity < 1 ? 1 : capacity;
  }

  /// Appends `item`; when the queue is full the oldest item is dropped first and returned (the
  /// caller warns about it).
  std::optional<T> push(T item) {
    std::optional<T> dropped;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (items_.size() >= capacity_) {
        dropped = std::move(items_.front());
        items_.pop_front();
      }
      items_.push_back(std::move(item));
    }
    cv_.notify_one();
    return dropped;
  }

  /// The oldest item, waiting for one; nothing once the queue is closed (items left are never
  /// handed out: the owner is shutting down).
  std::optional<T> pop() {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [this] { return closed_ || !items_.empty(); });
    if (closed_) return std::nullopt;
    T item = std::move(items_.front());
    items_.pop_front();
    return item;
  }

  /// Wakes every pop() for good.
  void close() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    cv_.notify_all();
  }

  size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }

 private:
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<T> items_;
  size_t capacity_;
  bool closed_ = false;
};

}  // namespace ros_glue
}  // namespace dtif
