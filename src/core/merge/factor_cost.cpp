#include "dtif/core/merge/factor_cost.h"

#include <suitesparse/amd.h>

#include <algorithm>
#include <stdexcept>

namespace dtif {

double choleskyMultiplies(size_t nodes, const std::vector<std::pair<size_t, size_t>>& edges) {
  if (nodes == 0) return 0.0;
  // The symmetric pattern in compressed columns, both triangles, no diagonal (amd_order's input).
  std::vector<std::vector<int>> columns(nodes);
  for (const auto& [a, b] : edges) {
    if (a == b || a >= nodes || b >= nodes) continue;
    columns[a].push_back(static_cast<int>(b));
    columns[b].push_back(static_cast<int>(a));
  }
  std::vector<int> Ap(nodes + 1, 0), Ai;
  for (size_t j = 0; j < nodes; ++j) {
    std::sort(columns[j].begin(), columns[j].end());
    columns[j].erase(std::unique(columns[j].begin(), columns[j].end()), columns[j].end());
    Ai.insert(Ai.end(), columns[j].begin(), columns[j].end());
    Ap[j + 1] = static_cast<int>(Ai.size());
  }
  // No off-diagonal entry: the factor is the diagonal itself. (amd_order refuses a null Ai as
  // an invalid matrix, and a map's first submaps have no edge yet.)
  if (Ai.empty()) return 0.0;
  std::vector<int> order(nodes);
  double info[AMD_INFO];
  const int status =
      amd_order(static_cast<int>(nodes), Ap.data(), Ai.data(), order.data(), nullptr, info);
  if (status != AMD_OK) {
    throw std::runtime_error("choleskyMultiplies: AMD ordering failed (status " +
                             std::to_string(status) + ")");
  }
  return info[AMD_NMULTSUBS_LDL];
}

}  // namespace dtif
