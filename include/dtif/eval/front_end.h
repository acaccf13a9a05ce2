// The online front end as the evaluation protocol runs it offline (DATASET.md, steps 1-4):
// per-robot levelling and trunk accumulation, the descriptor, the query against every earlier
// submap, the insert. runEvaluation scores each step; `dtif merge` runs the same steps on
// datasets without ground truth (a team's own bags), so they are levelled and accumulated alike.
#pragma once

#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/trunk_accumulator.h"
#include "dtif/core/extraction/gravity.h"
#include "dtif/io/config.h"
#include "dtif/io/dataset.h"

namespace dtif {

/// What one submap's steps 1-3 produced (the submap is not yet in the database).
struct FrontEndStep {
  Leveller::Result level;  ///< R_L_S used (identity when levelling is off)
  double level_ms = 0.0;
  std::shared_ptr<const Descriptor> desc;
  DescribeTimings timings;
  TrunkExtractionResult extraction;  ///< this submap's own trunks (in L)
  AccumulatedTrunks accumulated;
  /// The robot's earlier submaps described again with this one's stems (forward
  /// accumulation, multi_submap/forward_submaps): they replace their entries at insert.
  std::vector<std::shared_ptr<const Descriptor>> updates;
  std::optional<Loop> loop;  ///< the accepted loop, T_c_q in the submaps' own frames S
  /// Beside an own-robot `loop`: the best loop with another robot
  /// (database/inter_robot_verifications).
  std::optional<Loop> inter_robot_loop;
  QueryStats query;
  double loop_ms = 0.0;  ///< the query, verification included
  /// Step 1's time: the descriptor, plus levelling when it is on.
  double descMs(bool levelling) const { return timings.total_ms + (levelling ? level_ms : 0.0); }
};

class SequentialFrontEnd {
 public:
  explicit SequentialFrontEnd(const DtifParams& params);

  /// Steps 1-3 for the next submap in acquisition order: level (observed first, then levelled
  /// with the robot's estimate after it, as online), describe through the robot's accumulator,
  /// query.
  FrontEndStep describeAndQuery(const SubmapRecord& rec, const Cloud& cloud_S);
  /// Step 4: the described submap joins the database; the entries it extended forward are
  /// replaced (after its query: they are the same robot's recent submaps, not its candidates).
  void insert(const FrontEndStep& step);
  bool levelling() const { return leveller_.enabled(); }

 private:
  DtifParams params_;
  LoopDetector detector_;
  Leveller leveller_;
  std::map<std::string, TrunkAccumulator> accumulators_;  ///< per robot (multi_submap)
};

}  // namespace dtif
