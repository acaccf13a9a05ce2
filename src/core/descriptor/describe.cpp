// Extract -> describe -> stamp (see describe.h).
#include "dtif/core/descriptor/describe.h"

#include <chrono>
#include <utility>

#include "dtif/core/timing.h"

namespace dtif {
namespace {

void stamp(Descriptor* d, const SubmapKey& key, const Eigen::Quaterniond* level) {
  d->robot = key.robot;
  d->submap_id = key.submap_id;
  d->stamp = key.stamp;
  if (level) d->level_rotation = level->normalized();
}

// describeCloud before the byte budget; level (not null): the levelling rotation it records.
// The descriptor is made once the trunks are known, before the ground map, so that a map which
// the byte budget would drop is not built at all (fitDescriptorBytes keeps the rest as it is).
Descriptor describeUnfitted(const Cloud& cloud, const SubmapKey& key,
                            const Eigen::Quaterniond* level,
                            const TrunkExtractorParams& extractor_params,
                            const DescriptorParams& descriptor_params, DescribeTimings* timings,
                            TrunkExtractionResult* extraction) {
  const auto t0 = std::chrono::steady_clock::now();
  Descriptor d;
  bool described = false;
  double describe_ms = 0.0;
  const GroundMapWanted wanted = [&](const TrunkExtractionResult& without_map) {
    const auto t1 = std::chrono::steady_clock::now();
    d = describeSubmap(without_map, descriptor_params);
    stamp(&d, key, level);
    described = true;
    const bool fits = groundMapFits(d, descriptor_params.max_bytes);
    describe_ms = msSince(t1);
    return fits;
  };
  TrunkExtractionResult ext = extractTrunks(cloud, extractor_params, wanted);
  if (timings) timings->extract_ms = msSince(t0) - describe_ms;
  if (described) {
    d.ground_map = ext.ground_map;
  } else {
    d = describeSubmap(ext, descriptor_params);
    stamp(&d, key, level);
  }
  if (timings) timings->total_ms = msSince(t0);
  if (extraction) *extraction = std::move(ext);
  return d;
}

}  // namespace

Descriptor describeCloud(const Cloud& cloud_S, const SubmapKey& key,
                         const TrunkExtractorParams& extractor_params,
                         const DescriptorParams& descriptor_params, DescribeTimings* timings,
                         TrunkExtractionResult* extraction) {
  Descriptor d = describeUnfitted(cloud_S, key, nullptr, extractor_params, descriptor_params,
                                  timings, extraction);
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

Cloud rotateCloud(const Cloud& cloud, const Eigen::Quaterniond& R) {
  const Eigen::Matrix3f M = R.normalized().toRotationMatrix().cast<float>();
  Cloud out;
  out.resize(cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    out[i].getVector3fMap() = M * cloud[i].getVector3fMap();
  }
  out.width = static_cast<uint32_t>(out.size());
  out.height = 1;
  out.is_dense = cloud.is_dense;
  return out;
}

Descriptor describeLevelledCloud(const Cloud& cloud_S, const Eigen::Quaterniond& R_L_S,
                                 const SubmapKey& key, const TrunkExtractorParams& extractor_params,
                                 const DescriptorParams& descriptor_params,
                                 DescribeTimings* timings, TrunkExtractionResult* extraction) {
  const Eigen::Quaterniond identity = Eigen::Quaterniond::Identity();
  if (R_L_S.coeffs() == identity.coeffs()) {
    return describeCloud(cloud_S, key, extractor_params, descriptor_params, timings, extraction);
  }
  const auto t0 = std::chrono::steady_clock::now();
  const Cloud cloud_L = rotateCloud(cloud_S, R_L_S);
  const double rotate_ms = msSince(t0);
  Descriptor d = describeUnfitted(cloud_L, key, &R_L_S, extractor_params, descriptor_params,
                                  timings, extraction);
  if (timings) timings->total_ms += rotate_ms;
  fitDescriptorBytes(&d, descriptor_params.max_bytes);
  return d;
}

}  // namespace dtif
