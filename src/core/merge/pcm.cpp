#include "dtif/core/merge/pcm.h"

#include <algorithm>
#include <numeric>

namespace dtif {
namespace {

/// Branch and bound over candidates in index order (Carraghan-Pardalos): keeps the first
/// clique found of each size, so ties go to the smallest indices. The bound is a greedy
/// colouring of the remaining candidates (a clique needs as many colours as vertices; Tomita's
/// MCQ bound): it prunes only branches that cannot beat the best clique, so the result is the
/// one the plain size bound finds, in far fewer steps on the dense graphs loops make (hundreds
/// of mostly consistent loops: the size bound alone took minutes). A budget of expansions
/// bounds the worst case deterministically.
class CliqueSearch {
 public:
  CliqueSearch(const ConsistencyGraph& g, size_t budget) : g_(g), budget_(budget) {}

  std::vector<size_t> run() {
    std::vector<size_t> all(g_.size());
    std::iota(all.begin(), all.end(), 0);
    std::vector<size_t> current;
    expand(current, all);
    return best_;
  }
  bool exhausted() const { return expansions_ > budget_; }

 private:
  void expand(std::vector<size_t>& current, const std::vector<size_t>& candidates) {
    if (++expansions_ > budget_) return;
    if (current.size() > best_.size()) best_ = current;
    const std::vector<size_t> bound = suffixColourBounds(candidates);
    for (size_t k = 0; k < candidates.size(); ++k) {
      if (current.size() + bound[k] <= best_.size() || exhausted()) return;
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

  /// bound[k]: colours a greedy colouring of candidates[k..] uses (from the last candidate
  /// back, each the smallest colour none of its later neighbours has), an upper bound on any
  /// clique among them.
  std::vector<size_t> suffixColourBounds(const std::vector<size_t>& c) const {
    const size_t n = c.size();
    std::vector<size_t> colour(n), bound(n);
    std::vector<char> used(n + 1);
    size_t colours = 0;
    for (size_t i = n; i-- > 0;) {
      std::fill(used.begin(), used.begin() + static_cast<std::ptrdiff_t>(colours + 1), 0);
      for (size_t j = i + 1; j < n; ++j) {
        if (g_[c[i]][c[j]]) used[colour[j]] = 1;
      }
      size_t col = 0;
      while (used[col]) ++col;
      colour[i] = col;
      colours = std::max(colours, col + 1);
      bound[i] = colours;
    }
    return bound;
  }

  const ConsistencyGraph& g_;
  const size_t budget_;
  size_t expansions_ = 0;
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

std::vector<size_t> maximumClique(const ConsistencyGraph& graph, size_t exact_limit,
                                  size_t budget) {
  if (graph.empty()) return {};
  if (graph.size() > exact_limit) return greedyClique(graph);
  CliqueSearch search(graph, budget);
  std::vector<size_t> best = search.run();
  if (search.exhausted()) {
    std::vector<size_t> greedy = greedyClique(graph);
    if (greedy.size() > best.size()) best.swap(greedy);
  }
  return best;
}

}  // namespace dtif
