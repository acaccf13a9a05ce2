// FPFH global registration baseline (see fpfh_registration.h).
#include "dtif/baselines/fpfh_registration.h"

#include <pcl/features/fpfh_omp.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/search/kdtree.h>

#include <chrono>
#include <stdexcept>

#include "dtif/baselines/solvers.h"
#include "dtif/core/timing.h"

namespace dtif::baselines {

struct FpfhFeatures {
  pcl::PointCloud<pcl::PointXYZ>::Ptr points;
  pcl::PointCloud<pcl::FPFHSignature33>::Ptr features;
};

namespace {
using Clock = std::chrono::steady_clock;
}  // namespace

FpfhFeaturesPtr computeFpfh(const Cloud& cloud, const FpfhParams& params) {
  const auto in = cloud.makeShared();
  auto vox = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  pcl::VoxelGrid<pcl::PointXYZ> grid;
  grid.setInputCloud(in);
  grid.setLeafSize(params.voxel_m, params.voxel_m, params.voxel_m);
  grid.filter(*vox);
  // Keypoints: the voxels thinned evenly; normals and features use every voxel as the search
  // surface, so thinning drops keypoints, not the neighbourhoods that describe them.
  auto pts = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  const size_t step = vox->size() > params.max_points && params.max_points > 0
                          ? (vox->size() + params.max_points - 1) / params.max_points
                          : 1;
  for (size_t i = 0; i < vox->size(); i += step) pts->push_back((*vox)[i]);

  auto tree = pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>();
  auto normals = pcl::make_shared<pcl::PointCloud<pcl::Normal>>();
  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> ne(1);  // one thread: DATASET.md times
  ne.setInputCloud(vox);
  ne.setSearchMethod(tree);
  ne.setRadiusSearch(params.normal_radius_m);
  ne.compute(*normals);
  auto feats = pcl::make_shared<pcl::PointCloud<pcl::FPFHSignature33>>();
  pcl::FPFHEstimationOMP<pcl::PointXYZ, pcl::Normal, pcl::FPFHSignature33> fe(1);
  fe.setInputCloud(pts);
  fe.setSearchSurface(vox);
  fe.setInputNormals(normals);
  fe.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  fe.setRadiusSearch(params.feature_radius_m);
  fe.compute(*feats);
  auto out = std::make_shared<FpfhFeatures>();
  out->points = pts;
  out->features = feats;
  return out;
}

size_t fpfhPoints(const FpfhFeatures& f) { return f.points->size(); }
size_t fpfhBytes(const FpfhFeatures& f) {
  return f.points->size() * (3 * sizeof(float) + 33 * sizeof(float));
}

std::vector<Correspondence> matchFpfh(const FpfhFeatures& q, const FpfhFeatures& c) {
  std::vector<Correspondence> out;
  if (q.features->empty() || c.features->empty()) return out;
  // Signatures with a NaN (points without a normal) are left out of both trees.
  auto finite = [](const pcl::FPFHSignature33& s) {
    for (float v : s.histogram) {
      if (!std::isfinite(v)) return false;
    }
    return true;
  };
  auto valid = [&](const FpfhFeatures& f, std::vector<int>* idx) {
    auto cl = pcl::make_shared<pcl::PointCloud<pcl::FPFHSignature33>>();
    for (size_t i = 0; i < f.features->size(); ++i) {
      if (!finite((*f.features)[i])) continue;
      idx->push_back(static_cast<int>(i));
      cl->push_back((*f.features)[i]);
    }
    return cl;
  };
  std::vector<int> iq, ic;
  const auto fq = valid(q, &iq), fc = valid(c, &ic);
  if (fq->empty() || fc->empty()) return out;
  pcl::KdTreeFLANN<pcl::FPFHSignature33> tq, tc;
  tq.setInputCloud(fq);
  tc.setInputCloud(fc);
  std::vector<int> nn(1);
  std::vector<float> d2(1);
  std::vector<int> c_to_q(fc->size(), -1);
  for (size_t j = 0; j < fc->size(); ++j) {
    if (tq.nearestKSearch((*fc)[j], 1, nn, d2) == 1) c_to_q[j] = nn[0];
  }
  for (size_t i = 0; i < fq->size(); ++i) {
    if (tc.nearestKSearch((*fq)[i], 1, nn, d2) != 1) continue;
    if (c_to_q[nn[0]] != static_cast<int>(i)) continue;  // mutual only
    Correspondence k;
    k.iq = iq[i];
    k.ic = ic[nn[0]];
    const auto& a = (*q.points)[k.iq];
    const auto& b = (*c.points)[k.ic];
    k.pq = Eigen::Vector3d(a.x, a.y, a.z);
    k.pc = Eigen::Vector3d(b.x, b.y, b.z);
    out.push_back(k);
  }
  return out;
}

FpfhRegistration solveFpfh(const std::vector<Correspondence>& all, const FpfhParams& params) {
  FpfhRegistration r;
  r.correspondences = static_cast<int>(all.size());
  const auto t0 = Clock::now();
  std::vector<Correspondence> corrs;
  if (params.prune) {
    for (int i : greedyConsistentSet(all, 2.0 * params.inlier_m)) corrs.push_back(all[i]);
  } else {
    corrs = all;
  }
  PoseEstimate est;
  if (params.solver == "quatro") {
    QuatroParams p;
    p.beta_m = params.inlier_m;
    est = quatroLike(corrs, p);
  } else if (params.solver == "svd_ransac") {
    RansacParams p;
    p.inlier_m = params.inlier_m;
    est = svdRansac(corrs, p);
  } else {
    throw std::invalid_argument("unknown FPFH solver '" + params.solver + "'");
  }
  r.solver_ms = msSince(t0);
  if (!est.ok) return r;
  r.T_c_q = est.T_c_q;
  r.inliers = static_cast<int>(est.inliers_T.size());
  r.accepted = r.inliers >= params.min_inliers;
  return r;
}

FpfhRegistration registerFpfh(const FpfhFeatures& q, const FpfhFeatures& c,
                              const FpfhParams& params) {
  const auto t0 = Clock::now();
  const std::vector<Correspondence> corrs = matchFpfh(q, c);
  const double match_ms = msSince(t0);
  FpfhRegistration r = solveFpfh(corrs, params);
  r.match_ms = match_ms;
  return r;
}

}  // namespace dtif::baselines
