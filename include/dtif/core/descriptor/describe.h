// A submap cloud to its stamped descriptor: trunk extraction (Sec. 3.A), the descriptor of the
// trunks (Sec. 3.B), and the submap's identity. The one "extract -> describe -> stamp" path of
// the nodelet, the evaluation and the benchmark.
#pragma once

#include <cstdint>
#include <string>

#include "dtif/core/cloud.h"
#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/extraction/trunk_extractor.h"

namespace dtif {

/// Who made a submap and when: the identity fields a descriptor carries.
struct SubmapKey {
  std::string robot;
  int64_t submap_id = -1;
  double stamp = 0.0;  ///< submap anchor time [s]
};

/// Wall-clock durations of describeCloud's steps (steady clock).
struct DescribeTimings {
  double extract_ms = 0.0;  ///< extractTrunks alone [ms]
  double total_ms = 0.0;    ///< extractTrunks + describeSubmap, from the same start [ms]
};

/// extractTrunks(cloud_S), describeSubmap of the result, stamped with `key`. `timings` and
/// `extraction` (when not null) receive the durations and the extraction result (trunks in S,
/// for markers and detection statistics). Thread-safe; deterministic apart from the timings.
Descriptor describeCloud(const Cloud& cloud_S, const SubmapKey& key,
                         const TrunkExtractorParams& extractor_params,
                         const DescriptorParams& descriptor_params,
                         DescribeTimings* timings = nullptr,
                         TrunkExtractionResult* extraction = nullptr);

/// describeCloud of the submap rotated by R_L_S first (levelling, extraction/gravity.h): trunks
/// and descriptor in the levelled frame L, which the descriptor records (level_rotation). The
/// rotation counts in the timings. Identity: exactly describeCloud.
Descriptor describeLevelledCloud(const Cloud& cloud_S, const Eigen::Quaterniond& R_L_S,
                                 const SubmapKey& key, const TrunkExtractorParams& extractor_params,
                                 const DescriptorParams& descriptor_params,
                                 DescribeTimings* timings = nullptr,
                                 TrunkExtractionResult* extraction = nullptr);

/// The cloud rotated by R (levelling: R_L_S).
Cloud rotateCloud(const Cloud& cloud, const Eigen::Quaterniond& R);

}  // namespace dtif
