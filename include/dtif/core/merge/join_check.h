// The trunks around a loop that joins two robots: where both robots mapped the same ground, a
// true loop lays their trunks on each other, a false one (an aliased trunk pattern, a wrong
// pose) puts one robot's trunks where the other saw none. A check for the loops PCM cannot
// compare with others (a robot pair's only loop).
#pragma once

#include <Eigen/Core>
#include <vector>

namespace dtif {

/// One robot's side of a join: its submaps near the loop, in one common horizontal frame.
struct JoinSide {
  std::vector<Eigen::Vector2d> trunks;   ///< trunk centres of every submap (repeats kept)
  std::vector<Eigen::Vector2d> origins;  ///< the submaps' origins: where the trunks were seen from
};

struct TrunkAgreement {
  int compared = 0;  ///< trunks of either side within the zone of the other side's origins
  int matched = 0;   ///< of those, with a trunk of the other side within the gate
  double fraction() const { return compared > 0 ? static_cast<double>(matched) / compared : 0.0; }
};

/// Compares the trunks of each side that lie within zone_m of an origin of the other side
/// (ground the other robot saw at close range) with the other side's trunks: matched when one
/// lies within gate_m.
TrunkAgreement trunkAgreement(const JoinSide& a, const JoinSide& b, double zone_m, double gate_m);

}  // namespace dtif
