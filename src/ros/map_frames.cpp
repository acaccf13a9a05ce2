#include "dtif/ros/map_frames.h"

#include <algorithm>
#include <climits>

namespace dtif {
namespace ros_glue {

std::vector<MapFrames::Change> MapFrames::assign(
    const std::vector<std::set<std::string>>& components) {
  std::vector<const std::set<std::string>*> order;
  for (const auto& c : components) {
    if (!c.empty()) order.push_back(&c);
  }
  std::stable_sort(order.begin(), order.end(), [](const auto* a, const auto* b) {
    return a->size() != b->size() ? a->size() > b->size() : *a->begin() < *b->begin();
  });
  std::set<int> taken;
  std::vector<int> index(order.size(), -1);
  // Components keep the lowest frame their robots held, largest first.
  for (size_t i = 0; i < order.size(); ++i) {
    int best = INT_MAX;
    for (const std::string& r : *order[i]) {
      auto it = index_of_.find(r);
      if (it != index_of_.end() && !taken.count(it->second)) best = std::min(best, it->second);
    }
    if (best != INT_MAX) {
      index[i] = best;
      taken.insert(best);
    }
  }
  // The rest take the lowest free frames.
  int next = 0;
  for (size_t i = 0; i < order.size(); ++i) {
    if (index[i] >= 0) continue;
    while (taken.count(next)) ++next;
    index[i] = next;
    taken.insert(next);
  }
  std::vector<Change> changes;
  for (size_t i = 0; i < order.size(); ++i) {
    for (const std::string& r : *order[i]) {
      const std::string to = name(index[i]);
      const std::string from = frameOf(r);
      if (from != to) changes.push_back({r, from, to});
      index_of_[r] = index[i];
      frame_of_[r] = to;
    }
  }
  std::sort(changes.begin(), changes.end(),
            [](const Change& a, const Change& b) { return a.robot < b.robot; });
  return changes;
}

std::string MapFrames::frameOf(const std::string& robot) const {
  auto it = frame_of_.find(robot);
  return it == frame_of_.end() ? std::string() : it->second;
}

}  // namespace ros_glue
}  // namespace dtif
