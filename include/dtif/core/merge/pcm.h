// Pairwise consistency maximisation (PCM, Mangelson et al. 2018): loops between one pair of
// robots are pairwise consistent when the cycle two of them close with the robots' odometry
// chains is within its uncertainty; the largest mutually consistent set is kept.
#pragma once

#include <cstddef>
#include <vector>

namespace dtif {

/// Symmetric adjacency matrix, adjacency[i][j] = loops i and j are consistent.
using ConsistencyGraph = std::vector<std::vector<bool>>;

/// Maximum clique, as sorted vertex indices. Exact (branch and bound with a colouring bound)
/// up to `exact_limit` vertices and `budget` expansions of the search; above the limit, or when
/// the budget runs out, a greedy clique (vertices by degree) if it is larger than the best found,
/// maximal but maybe not maximum. Ties go to the clique of smallest indices; deterministic (the
/// budget counts steps, not time).
std::vector<size_t> maximumClique(const ConsistencyGraph& graph, size_t exact_limit = 200,
                                  size_t budget = 20000);

}  // namespace dtif
