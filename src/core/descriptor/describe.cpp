// Extract -> describe -> stamp (see describe.h).
#include "dtif/core/descriptor/describe.h"

#include <chrono>
#include <utility>

#include "dtif/core/timing.h"

namespace dtif {

Descriptor describeCloud(const Cloud& cloud_S, const SubmapKey& key,
                         const TrunkExtractorParams& extractor_params,
                         const DescriptorParams& descriptor_params, DescribeTimings* timings,
                         TrunkExtractionResult* extraction) {
  const auto t0 = std::chrono::steady_clock::now();
  TrunkExtractionResult ext = extractTrunks(cloud_S, extractor_params);
  if (timings) timings->extract_ms = msSince(t0);
  Descriptor d = describeSubmap(ext, descriptor_params);
  if (timings) timings->total_ms = msSince(t0);
  d.robot = key.robot;
  d.submap_id = key.submap_id;
  d.stamp = key.stamp;
  if (extraction) *extraction = std::move(ext);
  return d;
}

}  // namespace dtif
