// Hierarchical vertex correspondence construction (paper Sec. 3.C, Algorithm 1): histogram
// screening, edge-radius consistency (Eq. 3.4), strong/weak vertex support (Eqs. 3.5-3.8),
// reliability weights (Eq. 3.9), weighted correspondences (Eq. 3.10).
#pragma once

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "dtif/core/descriptor/descriptor.h"

namespace dtif {

struct MatcherParams {
  double min_edge_hist_sim = 0.55;   ///< tau_s^e: histogram intersection of h^e [0..1]
  double min_radius_hist_sim = 0.4;  ///< tau_s^r: histogram intersection of h^r [0..1]
  double edge_rel_tol = 0.04;        ///< Cons_l: |l_q - l_c| <= tol * max(l_q, l_c) [-]
  double edge_abs_tol_m = 0.15;      ///< Cons_l also passes within this absolute gap [m]
  double radius_rel_tol = 0.3;       ///< Cons_r: |r_q - r_c| <= tol * max(r_q, r_c) [-]
  double radius_abs_tol_m = 0.03;    ///< Cons_r also passes within this absolute gap [m]
  int weak_support_min = 2;          ///< tau_w: weak support must exceed this (Eq. 3.8)
  double alpha_s = 1.0;              ///< alpha_s of Eq. (3.9)
  double alpha_w = 0.25;             ///< alpha_w of Eq. (3.9); alpha_s > alpha_w
  int max_correspondences = 400;     ///< keep the heaviest K pairs at most
  /// Beyond the paper: besides the Delaunay faces, also match every triangle of a trunk and two
  /// of its k nearest neighbours (k = this). Two submaps that share only part of their trunks
  /// share few Delaunay faces (a trunk seen by one only changes them) but many such triangles.
  /// 0: Delaunay faces only, as in the paper.
  int neighbour_triangles = 4;
  /// Beyond the paper: when the triangles give no usable hypothesis, trunk pairs vote for a
  /// planar pose (pair_vote.h), and the best-fitting voted pose is verified like any other.
  bool vote_fallback = true;
  /// ... only when the triangles gave fewer correspondences than this (0: whatever their
  /// number). A repetitive stand's triangles fill all max_correspondences without a clear pose,
  /// and its trunk pairs vote as ambiguously (plantation: 7-120 ms a fallback, all rejected).
  int vote_max_correspondences = 400;
  double vote_max_pair_m = 6.0;   ///< longest trunk pair that votes [m]
  double vote_yaw_bin_deg = 2.0;  ///< yaw bin of the vote accumulator [deg]
  double vote_xy_bin_m = 0.5;     ///< translation bin of the vote accumulator [m]

  std::string validate() const;

  template <class V>
  void visit(V& v) {
    v("min_edge_hist_sim", min_edge_hist_sim);
    v("min_radius_hist_sim", min_radius_hist_sim);
    v("edge_rel_tol", edge_rel_tol);
    v("edge_abs_tol_m", edge_abs_tol_m);
    v("radius_rel_tol", radius_rel_tol);
    v("radius_abs_tol_m", radius_abs_tol_m);
    v("weak_support_min", weak_support_min);
    v("alpha_s", alpha_s);
    v("alpha_w", alpha_w);
    v("max_correspondences", max_correspondences);
    v("neighbour_triangles", neighbour_triangles);
    v("vote_fallback", vote_fallback);
    v("vote_max_correspondences", vote_max_correspondences);
    v("vote_max_pair_m", vote_max_pair_m);
    v("vote_yaw_bin_deg", vote_yaw_bin_deg);
    v("vote_xy_bin_m", vote_xy_bin_m);
  }
};

/// One weighted vertex correspondence (p_k^q, p_k^c, omega_k) of Eq. (3.10).
struct Correspondence {
  int iq = -1;  ///< query trunk index m
  int ic = -1;  ///< candidate trunk index n
  Eigen::Vector3d pq = Eigen::Vector3d::Zero();
  Eigen::Vector3d pc = Eigen::Vector3d::Zero();
  double w = 1.0;    ///< omega_mn, Eq. (3.9)
  bool z_ok = true;  ///< both stem bases were seen: the pair constrains the elevation
  int strong = 0;    ///< E^s_mn
  int weak = 0;      ///< E^w_mn
};

struct MatchStats {
  double edge_hist_sim = 0.0;    ///< s_e
  double radius_hist_sim = 0.0;  ///< s_r
  bool screened_out = false;     ///< rejected by Alg. 1 lines 4-7
  size_t triangle_pairs = 0;     ///< triangle pairs visited (after the length index)
};

/// A triangle buildCorrespondences matches, and whether it is a Delaunay face (the paper's
/// primitive) rather than a neighbour triangle (MatcherParams::neighbour_triangles).
struct MatchTriangle {
  Triangle t;
  bool delaunay = true;
};

/// For one (query) triangle, the candidate values that pass Cons_l with its edges ([0..2]) and
/// Cons_r with its radii ([3..5]): closed intervals that decide every finite value exactly as
/// Eq. (3.4)'s comparison does (validated descriptors hold finite trunks), so that a query's
/// are computed once and then tested against every candidate's triangles with two float
/// comparisons per value.
struct ConsistencyBounds {
  std::array<float, 6> lo{}, hi{};
  bool exact = true;  ///< false: a value is negative or not finite; pairs are tested directly
};

/// consistencyBounds of each triangle of t, in order.
std::vector<ConsistencyBounds> consistencyBounds(const std::vector<MatchTriangle>& t,
                                                 const MatcherParams& params);

/// The triangles matched for d: its Delaunay faces plus, with k > 0, every triangle of a trunk
/// and two of its k nearest neighbours (deduplicated), sorted by longest edge. Depends only on d
/// and k, so a database computes it once per descriptor, not once per pair. Pure; thread-safe.
std::vector<MatchTriangle> matchTriangles(const Descriptor& d, int k);

/// Histogram intersection S_cap(a, b) = sum_i min(a_i, b_i) of two normalised histograms.
double histogramIntersection(const std::vector<float>& a, const std::vector<float>& b);

/// Algorithm 1. Returns the weighted correspondences, heaviest first; empty when screened out.
/// Pure; thread-safe.
std::vector<Correspondence> buildCorrespondences(const Descriptor& query,
                                                 const Descriptor& candidate,
                                                 const MatcherParams& params,
                                                 MatchStats* stats = nullptr);
/// The same with the sides' matchTriangles(d, params.neighbour_triangles) and the query
/// triangles' consistencyBounds given (each nullptr is computed here).
std::vector<Correspondence> buildCorrespondences(
    const Descriptor& query, const Descriptor& candidate, const MatcherParams& params,
    MatchStats* stats, const std::vector<MatchTriangle>* query_triangles,
    const std::vector<MatchTriangle>* candidate_triangles,
    const std::vector<ConsistencyBounds>* query_bounds = nullptr);

}  // namespace dtif
