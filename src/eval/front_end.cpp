#include "dtif/eval/front_end.h"

#include <chrono>

#include "dtif/core/timing.h"

namespace dtif {

SequentialFrontEnd::SequentialFrontEnd(const DtifParams& params)
    : params_(params), detector_(params_.loop), leveller_(params_.levelling) {}

FrontEndStep SequentialFrontEnd::describeAndQuery(const SubmapRecord& rec, const Cloud& cloud_S) {
  FrontEndStep s;
  if (leveller_.enabled()) {
    const auto t0 = std::chrono::steady_clock::now();
    s.level = leveller_.level(rec.robot, cloud_S, Eigen::Quaterniond(rec.T_O_S.rotation()));
    s.level_ms = msSince(t0);
  }
  auto acc = accumulators_.try_emplace(rec.robot, params_.multi_submap).first;
  std::vector<Descriptor> updates;
  s.desc = std::make_shared<const Descriptor>(describeLevelledCloudAccumulated(
      cloud_S, s.level.R_L_S, {rec.robot, rec.id, rec.stamp}, rec.T_O_S, &acc->second,
      params_.trunk_extraction, params_.descriptor, &s.timings, &s.extraction, &s.accumulated,
      &updates));
  for (Descriptor& u : updates)
    s.updates.push_back(std::make_shared<const Descriptor>(std::move(u)));
  const auto t1 = std::chrono::steady_clock::now();
  s.loop = detector_.query(*s.desc, &s.query, &s.inter_robot_loop);
  s.loop_ms = msSince(t1);
  return s;
}

void SequentialFrontEnd::insert(const FrontEndStep& step) {
  detector_.insert(step.desc);
  for (const auto& u : step.updates) detector_.replace(u);
}

}  // namespace dtif
