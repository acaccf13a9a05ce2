#include "dtif/core/database/robot_links.h"

#include <queue>
#include <set>

namespace dtif {

void RobotLinks::add(const std::string& frame_a, const std::string& frame_b, const Pose& T_a_b) {
  if (frame_a == frame_b) return;
  links_[{frame_a, frame_b}] = T_a_b;
  links_.erase({frame_b, frame_a});
}

std::vector<RobotLinks::Edge> RobotLinks::spanningTree() const {
  // Both directions of every link; the map's order makes roots and neighbours sorted.
  std::map<std::string, std::vector<std::pair<std::string, Pose>>> adj;  // a -> (b, T_a_b)
  for (const auto& l : links_) {
    adj[l.first.first].emplace_back(l.first.second, l.second);
    adj[l.first.second].emplace_back(l.first.first, l.second.inverse());
  }
  std::vector<Edge> tree;
  std::set<std::string> seen;
  for (const auto& group : adj) {
    const std::string& root = group.first;
    if (seen.count(root)) continue;
    seen.insert(root);
    std::queue<std::string> todo;
    todo.push(root);
    while (!todo.empty()) {
      const std::string a = todo.front();
      todo.pop();
      for (const auto& e : adj.at(a)) {
        if (seen.count(e.first)) continue;
        seen.insert(e.first);
        todo.push(e.first);
        tree.push_back(Edge{a, e.first, e.second});
      }
    }
  }
  return tree;
}

}  // namespace dtif
