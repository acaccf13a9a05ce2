#include "dtif/core/merge/slice_alignment.h"

#include <ceres/ceres.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>

namespace dtif {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

/// A bark point's distance to its stem's circle after its view's correction, in point sigmas.
/// a: the point minus its view's origin; o: the origin minus the stem's seed (both M).
struct BarkResidual {
  Eigen::Vector2d a, o;
  double inv_sigma;
  template <class T>
  bool operator()(const T* view, const T* stem, T* e) const {
    const T cs = ceres::cos(view[2]), sn = ceres::sin(view[2]);
    const T x = cs * a.x() - sn * a.y() + view[0] + o.x() - stem[0];
    const T y = sn * a.x() + cs * a.y() + view[1] + o.y() - stem[1];
    e[0] = (ceres::sqrt(x * x + y * y) - stem[2]) * inv_sigma;
    return true;
  }
};

/// The prior drawing a view's correction towards none.
struct ViewPrior {
  double inv_sigma_m, inv_sigma_rad;
  template <class T>
  bool operator()(const T* view, T* e) const {
    e[0] = view[0] * inv_sigma_m;
    e[1] = view[1] * inv_sigma_m;
    e[2] = view[2] * inv_sigma_rad;
    return true;
  }
};

/// The indices of the points of stem `s` from view `v` that lie within inlier_m of its circle,
/// at most `cap` of them, evenly strided.
std::vector<size_t> inliersOfView(const AlignedSlice& s, uint32_t v, double inlier_m, size_t cap) {
  std::vector<size_t> idx;
  for (size_t j = 0; j < s.xy->size(); ++j) {
    if ((*s.view)[j] != v) continue;
    const Eigen::Vector2d p = (*s.xy)[j].cast<double>();
    if (std::abs(std::hypot(p.x() - s.cx, p.y() - s.cy) - s.r) < inlier_m) idx.push_back(j);
  }
  if (idx.size() <= cap) return idx;
  std::vector<size_t> kept(cap);
  for (size_t k = 0; k < cap; ++k) kept[k] = idx[k * idx.size() / cap];
  return kept;
}

}  // namespace

std::vector<ViewCorrection> alignSliceViews(const std::vector<Eigen::Vector2d>& origins,
                                            const std::vector<AlignedSlice>& stems, double inlier_m,
                                            const SliceAlignmentParams& p,
                                            SliceAlignmentStats* stats) {
  SliceAlignmentStats st;
  std::vector<ViewCorrection> out(origins.size());
  std::vector<std::array<double, 3>> view(origins.size(), {0.0, 0.0, 0.0});
  std::vector<std::array<double, 3>> circle(stems.size());
  std::vector<size_t> stems_of(origins.size(), 0);
  std::vector<Eigen::Vector2d> facing(origins.size(), Eigen::Vector2d::Zero());
  ceres::Problem problem;
  auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
  for (size_t k = 0; k < stems.size(); ++k) {
    const AlignedSlice& s = stems[k];
    circle[k] = {s.cx, s.cy, s.r};
    std::vector<uint32_t> views(s.view->begin(), s.view->end());
    std::sort(views.begin(), views.end());
    views.erase(std::unique(views.begin(), views.end()), views.end());
    bool any = false;
    for (uint32_t v : views) {
      const std::vector<size_t> inliers = inliersOfView(s, v, inlier_m, p.points_per_view);
      Eigen::Vector2d arc = Eigen::Vector2d::Zero();
      for (size_t j : inliers) {
        const Eigen::Vector2d pt = (*s.xy)[j].cast<double>();
        arc += (pt - Eigen::Vector2d(s.cx, s.cy)).normalized();
        auto* cost = new ceres::AutoDiffCostFunction<BarkResidual, 1, 3, 3>(
            new BarkResidual{pt + s.seed - origins[v], origins[v] - s.seed, 1.0 / p.point_sigma_m});
        problem.AddResidualBlock(cost, new ceres::CauchyLoss(p.loss_sigmas), view[v].data(),
                                 circle[k].data());
        ++st.points;
      }
      if (inliers.empty()) continue;
      ++stems_of[v], any = true;
      if (arc.norm() > 0.0) facing[v] += arc.normalized();
    }
    if (any) {
      ordering->AddElementToGroup(circle[k].data(), 0);  // eliminated first (Schur)
      ++st.stems;
    }
  }
  std::vector<char> corrected(origins.size(), 0);
  for (size_t v = 0; v < origins.size(); ++v) {
    if (stems_of[v] == 0) continue;
    ordering->AddElementToGroup(view[v].data(), 1);
    corrected[v] = stems_of[v] >= p.min_stems_per_view &&
                   facing[v].norm() <= p.max_facing_resultant * static_cast<double>(stems_of[v]);
    if (!corrected[v]) {
      problem.SetParameterBlockConstant(view[v].data());
      continue;
    }
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<ViewPrior, 3, 3>(
                                 new ViewPrior{1.0 / p.sigma_m, 1.0 / (p.sigma_deg * kDegToRad)}),
                             nullptr, view[v].data());
    ++st.views;
  }
  if (st.views > 0) {
    ceres::Solver::Options opt;
    // The reduced system is 3 x 3 per pair of views: dense for a few hundred submaps (a run of a
    // few units), sparse beyond (a fleet's thousands would need gigabytes dense).
    constexpr size_t kDenseMaxViews = 300;
    opt.linear_solver_type = st.views <= kDenseMaxViews ? ceres::DENSE_SCHUR : ceres::SPARSE_SCHUR;
    opt.linear_solver_ordering = ordering;
    opt.max_num_iterations = p.max_iterations;
    opt.num_threads = 1;
    opt.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(opt, &problem, &summary);
    for (size_t v = 0; v < origins.size(); ++v) {
      if (!corrected[v]) continue;
      out[v] = {view[v][0], view[v][1], view[v][2]};
      st.max_shift_m = std::max(st.max_shift_m, std::hypot(view[v][0], view[v][1]));
    }
  }
  if (stats) *stats = st;
  return out;
}

}  // namespace dtif
