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
/// a: the point minus its view's origin; o: the origin minus the stem's seed (both M, both
/// small: a stem's seed and a view's origin may be plot coordinates 500 km out).
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

/// The indices among [b, e) of stem s's points that lie within inlier_m of its circle, at most
/// `cap` of them, evenly strided.
std::vector<size_t> inliersOf(const AlignedSlice& s, size_t b, size_t e, double inlier_m,
                              size_t cap) {
  std::vector<size_t> idx;
  for (size_t j = b; j < e; ++j) {
    const Eigen::Vector2d p = (*s.xy)[j].cast<double>();
    if (std::abs(std::hypot(p.x() - s.cx, p.y() - s.cy) - s.r) < inlier_m) idx.push_back(j);
  }
  if (idx.size() <= cap) return idx;
  std::vector<size_t> kept(cap);
  for (size_t k = 0; k < cap; ++k) kept[k] = idx[k * idx.size() / cap];
  return kept;
}

/// The problem as it is built: the views' correction blocks, and per view the stems it has
/// inliers on and the sum of their arcs' unit facing vectors.
struct Alignment {
  explicit Alignment(size_t views)
      : view(views, {0.0, 0.0, 0.0}), stems_of(views, 0), facing(views, Eigen::Vector2d::Zero()) {}
  ceres::Problem problem;
  std::shared_ptr<ceres::ParameterBlockOrdering> ordering =
      std::make_shared<ceres::ParameterBlockOrdering>();
  std::vector<std::array<double, 3>> view;
  std::vector<size_t> stems_of;
  std::vector<Eigen::Vector2d> facing;
  SliceAlignmentStats st;
};

/// Stem s's residuals, one run of consecutive points per view, on its circle block.
void addStem(const AlignedSlice& s, const std::vector<Eigen::Vector2d>& origins, double inlier_m,
             const SliceAlignmentParams& p, std::array<double, 3>* circle, Alignment* al) {
  *circle = {s.cx, s.cy, s.r};
  const std::vector<uint32_t>& views = *s.view;
  bool any = false;
  for (size_t b = 0, e = 0; b < views.size(); b = e) {
    const uint32_t v = views[b];
    while (e < views.size() && views[e] == v) ++e;
    const std::vector<size_t> inliers = inliersOf(s, b, e, inlier_m, p.points_per_view);
    if (inliers.empty()) continue;
    const Eigen::Vector2d o = origins[v] - s.seed;
    Eigen::Vector2d arc = Eigen::Vector2d::Zero();
    for (size_t j : inliers) {
      const Eigen::Vector2d pt = (*s.xy)[j].cast<double>();
      arc += (pt - Eigen::Vector2d(s.cx, s.cy)).normalized();
      al->problem.AddResidualBlock(new ceres::AutoDiffCostFunction<BarkResidual, 1, 3, 3>(
                                       new BarkResidual{pt - o, o, 1.0 / p.point_sigma_m}),
                                   new ceres::CauchyLoss(p.loss_sigmas), al->view[v].data(),
                                   circle->data());
      ++al->st.points;
    }
    ++al->stems_of[v], any = true;
    if (arc.norm() > 0.0) al->facing[v] += arc.normalized();
  }
  if (!any) return;
  al->ordering->AddElementToGroup(circle->data(), 0);  // eliminated first (Schur)
  ++al->st.stems;
}

/// Whether view v is corrected; its prior if so, else its block held at none.
bool addView(size_t v, const SliceAlignmentParams& p, Alignment* al) {
  al->ordering->AddElementToGroup(al->view[v].data(), 1);
  const bool corrected =
      al->stems_of[v] >= p.min_stems_per_view &&
      al->facing[v].norm() <= p.max_facing_resultant * static_cast<double>(al->stems_of[v]);
  if (!corrected) {
    al->problem.SetParameterBlockConstant(al->view[v].data());
    return false;
  }
  al->problem.AddResidualBlock(new ceres::AutoDiffCostFunction<ViewPrior, 3, 3>(
                                   new ViewPrior{1.0 / p.sigma_m, 1.0 / (p.sigma_deg * kDegToRad)}),
                               nullptr, al->view[v].data());
  ++al->st.views;
  return true;
}

void solve(const SliceAlignmentParams& p, Alignment* al) {
  ceres::Solver::Options opt;
  // The reduced system is 3 x 3 per pair of views: dense for a few hundred submaps (a run of a
  // few units), sparse beyond (a fleet's thousands would need gigabytes dense).
  constexpr size_t kDenseMaxViews = 300;
  opt.linear_solver_type =
      al->st.views <= kDenseMaxViews ? ceres::DENSE_SCHUR : ceres::SPARSE_SCHUR;
  opt.linear_solver_ordering = al->ordering;
  opt.max_num_iterations = p.max_iterations;
  opt.num_threads = 1;
  opt.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(opt, &al->problem, &summary);
}

}  // namespace

std::vector<ViewCorrection> alignSliceViews(const std::vector<Eigen::Vector2d>& origins,
                                            const std::vector<AlignedSlice>& stems, double inlier_m,
                                            const SliceAlignmentParams& p,
                                            SliceAlignmentStats* stats) {
  Alignment al(origins.size());
  std::vector<std::array<double, 3>> circle(stems.size());  // parameter blocks: must not move
  for (size_t k = 0; k < stems.size(); ++k)
    addStem(stems[k], origins, inlier_m, p, &circle[k], &al);
  std::vector<char> corrected(origins.size(), 0);
  for (size_t v = 0; v < origins.size(); ++v)
    corrected[v] = al.stems_of[v] > 0 && addView(v, p, &al);
  std::vector<ViewCorrection> out(origins.size());
  if (al.st.views > 0) {
    solve(p, &al);
    for (size_t v = 0; v < origins.size(); ++v) {
      if (!corrected[v]) continue;
      out[v] = {al.view[v][0], al.view[v][1], al.view[v][2]};
      al.st.max_shift_m = std::max(al.st.max_shift_m, std::hypot(al.view[v][0], al.view[v][1]));
    }
  }
  if (stats) *stats = al.st;
  return out;
}

}  // namespace dtif
