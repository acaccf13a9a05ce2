// Pairwise consistency maximisation (PCM, Mangelson et al. 2018): loops between one pair of
// robots are pairwise consistent when the cycle two of them close with the robots' odometry
// chains is within its uncertainty; the largest mutually consistent set is kept.
#pragma once

#include <cstddef>
#include <vector>

namespace dtif {

/// Symmetric adjacency matrix, adjacency[i][j] = loops i and j are consistent.
using ConsistencyGraph = std::vector<std::vector<bool>>;

/// Maximum clique, as sorted vertex indices. Exact (branch and bound) up to `exact_limit`
/// vertices; above it a greedy clique (vertices by degree) that is maximal but maybe not
/// maximum. Ties go to the clique of smallest indices, so the result is deterministic.
std::vector<size_t> maximumClique(const ConsistencyGraph& graph, size_t exact_limit = 200);

}  // namespace dtif
