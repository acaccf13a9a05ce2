// Multi-submap trunk sets (see trunk_accumulator.h).
#include "dtif/core/descriptor/trunk_accumulator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <utility>
#include <vector>

#include "dtif/core/extraction/extraction_stages.h"
#include "dtif/core/timing.h"

namespace dtif {

std::string MultiSubmapParams::validate() const {
  std::ostringstream err;
  if (min_trunks < 0) err << "min_trunks must be >= 0; ";
  if (target_trunks < 3) err << "target_trunks must be >= 3; ";
  if (max_submaps < 0 || max_submaps > 100) err << "max_submaps must be in [0, 100]; ";
  if (!(max_span_m >= 0.0 && std::isfinite(max_span_m))) err << "max_span_m must be >= 0; ";
  if (!(max_span_s >= 0.0 && std::isfinite(max_span_s))) err << "max_span_s must be >= 0; ";
  if (!(merge_radius_m > 0.0 && merge_radius_m < 5.0)) {
    err << "merge_radius_m must be in (0, 5); ";
  }
  if (min_observations < 1) err << "min_observations must be >= 1; ";
  if (!(min_radius_m >= 0.0 && min_radius_m < 1.0)) err << "min_radius_m must be in [0, 1); ";
  return err.str();
}

void StemMerger::add(const TrunkLandmark& t, int source) {
  // The nearest stem within the radius that this source has not seen yet.
  int best = -1;
  double best_d = radius_;
  for (size_t i = 0; i < stems_.size(); ++i) {
    if (stems_[i].last_source == source) continue;
    const double d = std::hypot(stems_[i].t.x - t.x, stems_[i].t.y - t.y);
    if (d < best_d) best_d = d, best = static_cast<int>(i);
  }
  if (best < 0) {
    Stem s;
    s.t = t;
    s.first_source = source;
    stems_.push_back(s);
    best = static_cast<int>(stems_.size()) - 1;
  }
  Stem& s = stems_[best];
  // The first sighting keeps the position; a later seen base replaces an extrapolated one.
  if (!s.t.base_seen && t.base_seen) {
    s.t.z = t.z;
    s.t.base_seen = true;
  }
  s.r_sum += t.r;
  ++s.sightings;
  if (s.last_source != source) {
    ++s.sources;
    s.last_source = source;
  }
}

Trunks StemMerger::stable(int min_observations, int max_source) const {
  Trunks out;
  for (const Stem& s : stems_) {
    if (s.sources < min_observations || s.first_source > max_source) continue;
    TrunkLandmark t = s.t;
    t.r = s.r_sum / s.sightings;
    out.push_back(t);
  }
  return out;
}

AccumulatedTrunks TrunkAccumulator::add(double stamp, const Pose& T_O_S, const Trunks& trunks_S) {
  Entry current{stamp, T_O_S, trunks_S};
  AccumulatedTrunks out;
  if (params_.min_trunks > 0) {
    out = accumulate(current);
  } else {
    out.trunks = trunks_S;
  }
  // Predecessors older than the span can never be used again.
  history_.push_back(std::move(current));
  while (!history_.empty() && (stamp - history_.front().stamp > params_.max_span_s ||
                               history_.size() > static_cast<size_t>(params_.max_submaps))) {
    history_.pop_front();
  }
  return out;
}

AccumulatedTrunks TrunkAccumulator::accumulate(const Entry& current) const {
  AccumulatedTrunks out;
  out.trunks = current.trunks;
  StemMerger merger(params_.merge_radius_m);
  auto addSightings = [&](const Trunks& trunks, const Pose& T_S_k, int source) {
    for (const TrunkLandmark& t : trunks) {
      if (t.r < params_.min_radius_m) continue;
      const Eigen::Vector3d p = T_S_k * Eigen::Vector3d(t.x, t.y, t.z);
      TrunkLandmark s = t;
      s.x = p.x(), s.y = p.y(), s.z = p.z();
      // The odometry's vertical drift over a few submaps (0.1-0.3 m in 30 m) is as large as
      // the elevation a seen base measures: only the submap's own bases fix t_z and the tilt;
      // without them t_z comes from the submaps' own ground maps.
      if (source > 0) s.base_seen = false;
      merger.add(s, source);
    }
  };
  addSightings(current.trunks, Pose::Identity(), 0);
  // Predecessors newest first: the odometry between S and a recent one has drifted least.
  const Pose T_S_O = current.T_O_S.inverse();
  std::vector<double> span;  // origin distance of source k (k >= 1) at span[k - 1]
  for (auto it = history_.rbegin(); it != history_.rend(); ++it) {
    if (static_cast<int>(span.size()) >= params_.max_submaps) break;
    if (current.stamp - it->stamp > params_.max_span_s || it->stamp >= current.stamp) continue;
    const Pose T_S_k = T_S_O * it->T_O_S;
    const double d = T_S_k.translation().norm();
    if (d > params_.max_span_m) continue;
    span.push_back(d);
    addSightings(it->trunks, T_S_k, static_cast<int>(span.size()));
  }
  // No predecessor in reach (a robot's first submap), or enough of the submap's own trunks
  // seen again by a predecessor (a stand dense enough for one submap): its own trunks, as
  // without accumulation.
  if (span.empty()) return out;
  out.stable_own = static_cast<int>(merger.stable(params_.min_observations, 0).size());
  if (out.stable_own >= params_.min_trunks) return out;
  // As few predecessors as give target_trunks stable stems; stability is judged on all of them.
  const int n = static_cast<int>(span.size());
  for (int m = 0; m <= n; ++m) {
    Trunks stable = merger.stable(params_.min_observations, m);
    if (static_cast<int>(stable.size()) >= params_.target_trunks || m == n) {
      out.trunks = std::move(stable);
      out.submaps = m + 1;
      for (int k = 0; k < m; ++k) out.span_m = std::max(out.span_m, span[k]);
      break;
    }
  }
  return out;
}

namespace {

// The submap's ground map over its own trunks' box (what extractTrunks builds when few bases
// are seen): an accumulated descriptor carries no seen base from its predecessors, so its
// loops' elevation comes from the submaps' own bases or, failing those, from these maps.
GroundMap groundMapOfCloud(const Cloud& cloud_S, const Trunks& own, const TrunkExtractorParams& p) {
  if (!(p.ground_map_cell_m > 0.0) || own.empty()) return GroundMap();
  std::vector<float> x, y, z;
  x.reserve(cloud_S.size()), y.reserve(cloud_S.size()), z.reserve(cloud_S.size());
  for (const auto& q : cloud_S) {
    x.push_back(q.x), y.push_back(q.y), z.push_back(q.z);
  }
  return groundMapAroundTrunks(own, x.data(), y.data(), z.data(), x.size(), Eigen::Vector3d::Zero(),
                               p);
}

// The accumulated descriptor without a ground map, stamped (level, when not null: the
// levelling rotation it records).
Descriptor accumulatedDescriptor(const TrunkExtractionResult& ext, const SubmapKey& key,
                                 const Eigen::Quaterniond* level, const Pose& T_O_S,
                                 TrunkAccumulator* accumulator,
                                 const DescriptorParams& descriptor_params,
                                 AccumulatedTrunks* acc) {
  *acc = accumulator->add(key.stamp, T_O_S, ext.trunks);
  Descriptor d = buildDescriptor(acc->trunks, descriptor_params);
  d.footprint = ext.footprint;
  d.robot = key.robot;
  d.submap_id = key.submap_id;
  d.stamp = key.stamp;
  if (level) d.level_rotation = level->normalized();
  return d;
}

// describeCloudAccumulated before the byte budget. As describeCloud, the descriptor is made
// before the ground map, and no map is built that the byte budget would drop.
Descriptor describeAccumulatedUnfitted(const Cloud& cloud_S, const SubmapKey& key,
                                       const Eigen::Quaterniond* level, const Pose& T_O_S,
                                       TrunkAccumulator* accumulator,
                                       const TrunkExtractorParams& extractor_params,
                                       const DescriptorParams& descriptor_params,
                                       DescribeTimings* timings, TrunkExtractionResult* extraction,
                                       AccumulatedTrunks* accumulated) {
  const auto t0 = std::chrono::steady_clock::now();
  Descriptor d;
  AccumulatedTrunks acc;
  bool described = false, fits = true;
  double describe_ms = 0.0;
  const GroundMapWanted wanted = [&](const TrunkExtractionResult& without_map) {
    const auto t1 = std::chrono::steady_clock::now();
    d = accumulatedDescriptor(without_map, key, level, T_O_S, accumulator, descriptor_params, &acc);
    described = true;
    fits = groundMapFits(d, descriptor_params.max_bytes);
    describe_ms = msSince(t1);
    return fits;
  };
  TrunkExtractionResult ext = extractTrunks(cloud_S, extractor_params, wanted);
  if (timings) timings->extract_ms = msSince(t0) - describe_ms;
  if (!described)
    d = accumulatedDescriptor(ext, key, level, T_O_S, accumulator, descriptor_params, &acc);
  d.ground_map = ext.ground_map;
  if (acc.submaps > 1 && d.ground_map.empty() &&
      (described ? fits : groundMapFits(d, descriptor_params.max_bytes))) {
    d.ground_map = groundMapOfCloud(cloud_S, ext.trunks, extractor_params);
  }
  if (timings) timings->total_ms = msSince(t0);
  if (extraction) *extraction = std::move(ext);
  if (accumulated) *accumulated = std::move(acc);
  return d;
}

}  // namespace

Descriptor describeCloudAccumulated(const Cloud& cloud_S, const SubmapKey& key, const Pose& T_O_S,
                                    TrunkAccumulator* accumulator,
                                    const TrunkExtractorParams& extractor_params,
                                    const DescriptorParams& descriptor_params,
                                    DescribeTimings* timings, TrunkExtractionResult* extraction,
                                    AccumulatedTrunks* accumulated) {
  Descriptor d =
      describeAccumulatedUnfitted(cloud_S, key, nullptr, T_O_S, accumulator, extractor_params,
                                  descriptor_params, timings, extraction, accumulated);
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

Descriptor describeLevelledCloudAccumulated(
    const Cloud& cloud_S, const Eigen::Quaterniond& R_L_S, const SubmapKey& key, const Pose& T_O_S,
    TrunkAccumulator* accumulator, const TrunkExtractorParams& extractor_params,
    const DescriptorParams& descriptor_params, DescribeTimings* timings,
    TrunkExtractionResult* extraction, AccumulatedTrunks* accumulated) {
  if (R_L_S.coeffs() == Eigen::Quaterniond::Identity().coeffs()) {
    return describeCloudAccumulated(cloud_S, key, T_O_S, accumulator, extractor_params,
                                    descriptor_params, timings, extraction, accumulated);
  }
  const auto t0 = std::chrono::steady_clock::now();
  const Cloud cloud_L = rotateCloud(cloud_S, R_L_S);
  const double rotate_ms = msSince(t0);
  Pose T_O_L = T_O_S;
  T_O_L.linear() = T_O_S.rotation() * R_L_S.normalized().conjugate().toRotationMatrix();
  Descriptor d =
      describeAccumulatedUnfitted(cloud_L, key, &R_L_S, T_O_L, accumulator, extractor_params,
                                  descriptor_params, timings, extraction, accumulated);
  if (timings) timings->total_ms += rotate_ms;
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

}  // namespace dtif
