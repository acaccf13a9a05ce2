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
  if (forward_submaps < 0 || forward_submaps > 100) err << "forward_submaps must be in [0, 100]; ";
  if (!(open_stand_share >= 0.0 && open_stand_share <= 1.0)) {
    err << "open_stand_share must be in [0, 1]; ";
  }
  if (open_stand_trunks < 0) err << "open_stand_trunks must be >= 0; ";
  if (open_stand_window < 1 || open_stand_window > 1000) {
    err << "open_stand_window must be in [1, 1000]; ";
  }
  if (open_stand_min_submaps < 1 || open_stand_min_submaps > open_stand_window) {
    err << "open_stand_min_submaps must be in [1, open_stand_window]; ";
  }
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

namespace {

double median(std::vector<double>* v) {
  std::sort(v->begin(), v->end());
  const size_t n = v->size();
  return n % 2 ? (*v)[n / 2] : 0.5 * ((*v)[n / 2 - 1] + (*v)[n / 2]);
}

}  // namespace

AccumulatedTrunks TrunkAccumulator::add(double stamp, const Pose& T_O_S, const Trunks& trunks_S,
                                        std::vector<ForwardUpdate>* updates) {
  Entry current;
  current.stamp = stamp, current.T_O_S = T_O_S, current.trunks = trunks_S;
  AccumulatedTrunks out;
  if (params_.min_trunks > 0) {
    out = accumulate(current);
  } else {
    out.trunks = trunks_S;
  }
  // Not extended only when enough of its own trunks were seen again (and the stand is not
  // open): more sources (its successors) only add sightings, so it would stay so.
  current.extended = out.submaps > 1 || out.stable_own < params_.min_trunks || out.open_stand;
  // A submap described with its own trunks keeps what a later description takes too when it
  // looks like an open stand's on its own: if the robot's stand turns out open once the medians
  // have enough submaps, it is described again with stable stems like the rest (else a robot's
  // first submaps, on which the medians are still being gathered, kept their one-off fits).
  current.updatable = current.extended || looksOpen(out.stable_own, trunks_S.size());
  current.described_own = out.ownOnly();
  if (out.stable_own >= 0 && !trunks_S.empty()) {
    stability_.push_back({static_cast<double>(out.stable_own) / trunks_S.size(), out.stable_own});
    while (stability_.size() > static_cast<size_t>(params_.open_stand_window)) {
      stability_.pop_front();
    }
  }
  open_ = openStandWith(nullptr);
  // Submaps older than the span can never be used again, nor be updated.
  history_.push_back(std::move(current));
  // The predecessors of the next submap, and those of the oldest one forward updates reach.
  const size_t keep = static_cast<size_t>(params_.max_submaps) +
                      (params_.forward_submaps > 0 ? params_.forward_submaps + 1 : 0);
  while (!history_.empty() &&
         (stamp - history_.front().stamp > params_.max_span_s || history_.size() > keep)) {
    history_.pop_front();
  }
  if (params_.min_trunks > 0 && params_.forward_submaps > 0) forwardUpdates(updates);
  return out;
}

bool TrunkAccumulator::newestMayBeUpdated() const {
  return params_.min_trunks > 0 && params_.forward_submaps > 0 && !history_.empty() &&
         history_.back().updatable;
}

bool TrunkAccumulator::belowOpenStand(double share, double stable) const {
  return params_.open_stand_share > 0.0 && share < params_.open_stand_share &&
         stable < static_cast<double>(params_.open_stand_trunks);
}

bool TrunkAccumulator::openStandWith(const Stability* extra) const {
  if (!(params_.open_stand_share > 0.0)) return false;
  std::vector<Stability> v(stability_.begin(), stability_.end());
  if (extra) {
    v.push_back(*extra);
    if (v.size() > static_cast<size_t>(params_.open_stand_window)) v.erase(v.begin());
  }
  if (v.empty() || v.size() < static_cast<size_t>(params_.open_stand_min_submaps)) return false;
  std::vector<double> share, stable;
  for (const Stability& s : v) share.push_back(s.share), stable.push_back(s.stable);
  return belowOpenStand(median(&share), median(&stable));
}

bool TrunkAccumulator::looksOpen(int stable_own, size_t own) const {
  return stable_own >= 0 && own > 0 &&
         belowOpenStand(static_cast<double>(stable_own) / static_cast<double>(own), stable_own);
}

void TrunkAccumulator::setFrameOfNewest(std::shared_ptr<const Descriptor> frame) {
  if (!history_.empty()) history_.back().frame = std::move(frame);
}

std::shared_ptr<const Descriptor> TrunkAccumulator::frameOf(double stamp) const {
  for (auto it = history_.rbegin(); it != history_.rend(); ++it) {
    if (it->stamp == stamp) return it->frame;
  }
  return nullptr;
}

void TrunkAccumulator::forwardUpdates(std::vector<ForwardUpdate>* updates) {
  const Entry& newest = history_.back();
  const Pose T_S_O = newest.T_O_S.inverse();
  for (size_t i = 0; i + 1 < history_.size(); ++i) {
    Entry& e = history_[i];
    if (newest.stamp - e.stamp > params_.max_span_s ||
        (T_S_O * e.T_O_S).translation().norm() > params_.max_span_m) {
      continue;
    }
    if (++e.successors > params_.forward_submaps || !e.updatable || (!e.extended && !open_)) {
      continue;
    }
    ForwardUpdate u;
    u.stamp = e.stamp;
    u.trunks = accumulateBothWays(i, &u.successors);
    // Its own trunks, as it was described: nothing to replace.
    const bool own = u.trunks.ownOnly();
    if (own && e.described_own) continue;
    e.described_own = own;
    if (updates) updates->push_back(std::move(u));
  }
}

namespace {

// Adds a submap's sightings, brought into S by T_S_k, to the merger as `source`.
void addSightings(const Trunks& trunks, const Pose& T_S_k, int source, double min_radius_m,
                  StemMerger* merger) {
  for (const TrunkLandmark& t : trunks) {
    if (t.r < min_radius_m) continue;
    const Eigen::Vector3d p = T_S_k * Eigen::Vector3d(t.x, t.y, t.z);
    TrunkLandmark s = t;
    s.x = p.x(), s.y = p.y(), s.z = p.z();
    // The odometry's vertical drift over a few submaps (0.1-0.3 m in 30 m) is as large as
    // the elevation a seen base measures: only the submap's own bases fix t_z and the tilt;
    // without them t_z comes from the submaps' own ground maps.
    if (source > 0) s.base_seen = false;
    merger->add(s, source);
  }
}

// The stable stems of sources [0, m] for the smallest m that gives target stems (or all of
// them); `out` holds the own trunks on entry and keeps them when enough of those are stable.
// With `open` (an open stand) the stable stems are taken however many own trunks are stable.
void chooseStable(const StemMerger& merger, const std::vector<double>& span,
                  const MultiSubmapParams& params, bool open, AccumulatedTrunks* out) {
  if (out->stable_own >= params.min_trunks && !open) return;
  out->open_stand = open;
  const int n = static_cast<int>(span.size());
  for (int m = 0; m <= n; ++m) {
    Trunks stable = merger.stable(params.min_observations, m);
    if (static_cast<int>(stable.size()) >= params.target_trunks || m == n) {
      out->trunks = std::move(stable);
      out->submaps = m + 1;
      for (int k = 0; k < m; ++k) out->span_m = std::max(out->span_m, span[k]);
      return;
    }
  }
}

}  // namespace

AccumulatedTrunks TrunkAccumulator::accumulate(const Entry& current) const {
  AccumulatedTrunks out;
  out.trunks = current.trunks;
  StemMerger merger(params_.merge_radius_m);
  addSightings(current.trunks, Pose::Identity(), 0, params_.min_radius_m, &merger);
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
    addSightings(it->trunks, T_S_k, static_cast<int>(span.size()), params_.min_radius_m, &merger);
  }
  // No predecessor in reach (a robot's first submap), or enough of the submap's own trunks
  // seen again by a predecessor (a stand dense enough for one submap): its own trunks, as
  // without accumulation.
  if (span.empty()) return out;
  out.stable_own = static_cast<int>(merger.stable(params_.min_observations, 0).size());
  const Stability own{static_cast<double>(out.stable_own) / current.trunks.size(), out.stable_own};
  const bool open = !current.trunks.empty() && openStandWith(&own);
  chooseStable(merger, span, params_, open, &out);
  return out;
}

AccumulatedTrunks TrunkAccumulator::accumulateBothWays(size_t i, int* successors) const {
  const Entry& e = history_[i];
  AccumulatedTrunks out;
  out.trunks = e.trunks;
  // The other submaps in reach, nearest in time first (the odometry between them and S has
  // drifted least), at most max_submaps before and forward_submaps after.
  struct Source {
    double dt;
    size_t index;
    Pose T_S_k;
    double d;
  };
  std::vector<Source> sources;
  const Pose T_S_O = e.T_O_S.inverse();
  int before = 0, after = 0;
  for (size_t k = history_.size(); k-- > 0;) {
    if (k == i) continue;
    const double dt = std::fabs(history_[k].stamp - e.stamp);
    const Pose T_S_k = T_S_O * history_[k].T_O_S;
    const double d = T_S_k.translation().norm();
    if (dt > params_.max_span_s || d > params_.max_span_m) continue;
    int& count = k < i ? before : after;
    if (count >= (k < i ? params_.max_submaps : params_.forward_submaps)) continue;
    ++count;
    sources.push_back({dt, k, T_S_k, d});
  }
  if (sources.empty()) return out;
  std::stable_sort(sources.begin(), sources.end(),
                   [](const Source& a, const Source& b) { return a.dt < b.dt; });
  StemMerger merger(params_.merge_radius_m);
  addSightings(e.trunks, Pose::Identity(), 0, params_.min_radius_m, &merger);
  std::vector<double> span;
  for (const Source& s : sources) {
    span.push_back(s.d);
    addSightings(history_[s.index].trunks, s.T_S_k, static_cast<int>(span.size()),
                 params_.min_radius_m, &merger);
  }
  out.stable_own = static_cast<int>(merger.stable(params_.min_observations, 0).size());
  chooseStable(merger, span, params_, open_, &out);
  if (successors) {
    *successors = 0;
    for (int m = 0; m + 1 < out.submaps; ++m) *successors += sources[m].index > i ? 1 : 0;
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

// A description other than the submap's own trunks keeps those beside it (what it observed).
void markAccumulated(const AccumulatedTrunks& acc, const Trunks& own, Descriptor* d) {
  d->accumulated = !acc.ownOnly();
  if (d->accumulated) d->own_trunks = own;
}

// What a forward update needs of the newest submap besides trunks: d without trunks and faces,
// with the ground map an extended description carries (from its own cloud).
std::shared_ptr<const Descriptor> forwardFrame(const Descriptor& d, const Cloud& cloud_S,
                                               const Trunks& own,
                                               const TrunkExtractorParams& extractor_params) {
  auto frame = std::make_shared<Descriptor>();
  frame->robot = d.robot, frame->submap_id = d.submap_id, frame->stamp = d.stamp;
  frame->own_trunks = own;
  frame->footprint = d.footprint;
  frame->ground_map = d.ground_map;
  if (frame->ground_map.empty()) {
    frame->ground_map = groundMapOfCloud(cloud_S, own, extractor_params);
  }
  frame->level_rotation = d.level_rotation;
  return frame;
}

// The forward updates of add() as descriptors, from the frames attached to their submaps.
void describeUpdates(const TrunkAccumulator& accumulator, const std::vector<ForwardUpdate>& u,
                     const DescriptorParams& descriptor_params, std::vector<Descriptor>* out) {
  for (const ForwardUpdate& f : u) {
    const std::shared_ptr<const Descriptor> frame = accumulator.frameOf(f.stamp);
    if (frame) out->push_back(describeForwardUpdate(*frame, f.trunks, descriptor_params));
  }
}

// The accumulated descriptor without a ground map, stamped (level, when not null: the
// levelling rotation it records); the forward updates the new submap makes due go to *forward.
Descriptor accumulatedDescriptor(const TrunkExtractionResult& ext, const SubmapKey& key,
                                 const Eigen::Quaterniond* level, const Pose& T_O_S,
                                 TrunkAccumulator* accumulator,
                                 const DescriptorParams& descriptor_params, AccumulatedTrunks* acc,
                                 std::vector<ForwardUpdate>* forward) {
  *acc = accumulator->add(key.stamp, T_O_S, ext.trunks, forward);
  Descriptor d = buildDescriptor(acc->trunks, descriptor_params);
  markAccumulated(*acc, ext.trunks, &d);
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
                                       AccumulatedTrunks* accumulated,
                                       std::vector<Descriptor>* updates) {
  const auto t0 = std::chrono::steady_clock::now();
  Descriptor d;
  AccumulatedTrunks acc;
  std::vector<ForwardUpdate> forward;
  bool described = false, fits = true;
  double describe_ms = 0.0;
  const GroundMapWanted wanted = [&](const TrunkExtractionResult& without_map) {
    const auto t1 = std::chrono::steady_clock::now();
    d = accumulatedDescriptor(without_map, key, level, T_O_S, accumulator, descriptor_params, &acc,
                              &forward);
    described = true;
    fits = groundMapFits(d, descriptor_params.max_bytes);
    describe_ms = msSince(t1);
    return fits;
  };
  TrunkExtractionResult ext = extractTrunks(cloud_S, extractor_params, wanted);
  if (timings) timings->extract_ms = msSince(t0) - describe_ms;
  if (!described) {
    d = accumulatedDescriptor(ext, key, level, T_O_S, accumulator, descriptor_params, &acc,
                              &forward);
  }
  d.ground_map = ext.ground_map;
  if (acc.submaps > 1 && d.ground_map.empty() &&
      (described ? fits : groundMapFits(d, descriptor_params.max_bytes))) {
    d.ground_map = groundMapOfCloud(cloud_S, ext.trunks, extractor_params);
  }
  // A submap that may be described again later keeps what that takes.
  if (accumulator->newestMayBeUpdated())
    accumulator->setFrameOfNewest(forwardFrame(d, cloud_S, ext.trunks, extractor_params));
  if (updates) describeUpdates(*accumulator, forward, descriptor_params, updates);
  if (timings) timings->total_ms = msSince(t0);
  if (extraction) *extraction = std::move(ext);
  if (accumulated) *accumulated = std::move(acc);
  return d;
}

}  // namespace

Descriptor describeForwardUpdate(const Descriptor& frame, const AccumulatedTrunks& trunks,
                                 const DescriptorParams& descriptor_params) {
  Descriptor d = buildDescriptor(trunks.trunks, descriptor_params);
  markAccumulated(trunks, frame.own_trunks, &d);
  d.robot = frame.robot, d.submap_id = frame.submap_id, d.stamp = frame.stamp;
  d.footprint = frame.footprint;
  d.ground_map = frame.ground_map;
  d.level_rotation = frame.level_rotation;
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

Descriptor describeCloudAccumulated(const Cloud& cloud_S, const SubmapKey& key, const Pose& T_O_S,
                                    TrunkAccumulator* accumulator,
                                    const TrunkExtractorParams& extractor_params,
                                    const DescriptorParams& descriptor_params,
                                    DescribeTimings* timings, TrunkExtractionResult* extraction,
                                    AccumulatedTrunks* accumulated,
                                    std::vector<Descriptor>* updates) {
  Descriptor d =
      describeAccumulatedUnfitted(cloud_S, key, nullptr, T_O_S, accumulator, extractor_params,
                                  descriptor_params, timings, extraction, accumulated, updates);
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

Descriptor describeLevelledCloudAccumulated(
    const Cloud& cloud_S, const Eigen::Quaterniond& R_L_S, const SubmapKey& key, const Pose& T_O_S,
    TrunkAccumulator* accumulator, const TrunkExtractorParams& extractor_params,
    const DescriptorParams& descriptor_params, DescribeTimings* timings,
    TrunkExtractionResult* extraction, AccumulatedTrunks* accumulated,
    std::vector<Descriptor>* updates) {
  if (R_L_S.coeffs() == Eigen::Quaterniond::Identity().coeffs()) {
    return describeCloudAccumulated(cloud_S, key, T_O_S, accumulator, extractor_params,
                                    descriptor_params, timings, extraction, accumulated, updates);
  }
  const auto t0 = std::chrono::steady_clock::now();
  const Cloud cloud_L = rotateCloud(cloud_S, R_L_S);
  const double rotate_ms = msSince(t0);
  Pose T_O_L = T_O_S;
  T_O_L.linear() = T_O_S.rotation() * R_L_S.normalized().conjugate().toRotationMatrix();
  Descriptor d =
      describeAccumulatedUnfitted(cloud_L, key, &R_L_S, T_O_L, accumulator, extractor_params,
                                  descriptor_params, timings, extraction, accumulated, updates);
  if (timings) timings->total_ms += rotate_ms;
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

}  // namespace dtif
