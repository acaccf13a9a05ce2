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

/// Grows a clique from the vertex of highest degree, each time adding the candidate with the
/// most neighbours among the remaining candidates (ties: smallest index).
std::vector<size_t> greedyClique(const ConsistencyGraph& g) {
  std::vector<size_t> candidates(g.size());
  std::iota(candidates.begin(), candidates.end(), 0);
  std::vector<size_t> clique;
  while (!candidates.empty()) {
    size_t best = candidates.front(), best_deg = 0;
    bool first = true;
    for (size_t v : candidates) {
      size_t deg = 0;
      for (size_t u : candidates) deg += u != v && g[v][u];
      if (first || deg > best_deg) {
        best = v;
        best_deg = deg;
        first = false;
      }
    }
    clique.push_back(best);
    std::vector<size_t> next;
    for (size_t u : candidates) {
      if (u != best && g[best][u]) next.push_back(u);
    }
    candidates.swap(next);
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
