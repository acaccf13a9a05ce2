// What a sparse Cholesky factorisation of the pose graph would cost, before choosing the linear
// solver (map_merger.cpp).
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

namespace dtif {

/// Multiply-subtract pairs of an LDL' factorisation of a graph's node-level pattern (one
/// scalar per node, an edge per off-diagonal pair) under approximate minimum degree ordering:
/// SuiteSparse AMD's own estimate, the ordering Ceres's sparse Cholesky uses. Self-loops and
/// repeated edges are ignored; returns 0 for a graph without edges.
double choleskyMultiplies(size_t nodes, const std::vector<std::pair<size_t, size_t>>& edges);

}  // namespace dtif
