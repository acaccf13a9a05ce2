#include "dtif/core/merge/pcm.h"

#include <algorithm>
#include <numeric>

namespace dtif {
namespace {

/// Branch and bound over candidates in index order (Carraghan-Pardalos): keeps the first
/// clique found of each size, so ties go to the smallest indices.
class CliqueSearch {
 public:
  explicit CliqueSearch(const ConsistencyGraph& g) : g_(g) {}

  std::vector<size_t> run() {
    std::vector<size_t> all(g_.size());
    std::iota(all.begin(), all.end(), 0);
    std::vector<size_t> current;
    expand(current, all);
    return best_;
  }

 private:
  void expand(std::vector<size_t>& current, const std::vector<size_t>& candidates) {
    if (current.size() > best_.size()) best_ = current;
    for (size_t k = 0; k < candidates.size(); ++k) {
      if (current.size() + (candidates.size() - k) <= best_.size()) return;  // bound
      const size_t v = candidates[k];
      std::vector<size_t> next;
      for (size_t m = k + 1; m < candidates.size(); ++m) {
        if (g_[v][candidates[m]]) next.push_back(candidates[m]);
      }
      current.push_back(v);
      expand(current, next);
      current.pop_back();
    }
  }

  const ConsistencyGraph& g_;
  std::vector<size_t> best_;
};

std::vector<size_t> greedyClique(const ConsistencyGraph& g) {
  std::vector<size_t> order(g.size());
  std::iota(order.begin(), order.end(), 0);
  std::vector<size_t> degree(g.size(), 0);
  for (size_t i = 0; i < g.size(); ++i) degree[i] = std::count(g[i].begin(), g[i].end(), true);
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return degree[a] > degree[b]; });
  std::vector<size_t> clique;
  for (size_t v : order) {
    if (std::all_of(clique.begin(), clique.end(), [&](size_t u) { return g[u][v]; })) {
      clique.push_back(v);
    }
  }
  std::sort(clique.begin(), clique.end());
  return clique;
}

}  // namespace

std::vector<size_t> maximumClique(const ConsistencyGraph& graph, size_t exact_limit) {
  if (graph.empty()) return {};
  if (graph.size() > exact_limit) return greedyClique(graph);
  return CliqueSearch(graph).run();
}

}  // namespace dtif
