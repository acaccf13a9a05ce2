#include "dtif/core/merge/join_check.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "dtif/core/cells.h"

namespace dtif {
namespace {

/// Points bucketed in square cells of one size, for "is any point within d" (d <= cell).
class PointGrid {
 public:
  PointGrid(const std::vector<Eigen::Vector2d>& pts, double cell) : pts_(pts), cell_(cell) {
    for (size_t i = 0; i < pts.size(); ++i)
      cells_[packCell(cell_of(pts[i].x()), cell_of(pts[i].y()))].push_back(i);
  }
  bool anyWithin(const Eigen::Vector2d& p, double d) const {
    const int64_t cx = cell_of(p.x()), cy = cell_of(p.y());
    for (int64_t dx = -1; dx <= 1; ++dx) {
      for (int64_t dy = -1; dy <= 1; ++dy) {
        const auto it = cells_.find(packCell(cx + dx, cy + dy));
        if (it == cells_.end()) continue;
        for (size_t i : it->second) {
          if ((pts_[i] - p).squaredNorm() <= d * d) return true;
        }
      }
    }
    return false;
  }

 private:
  int64_t cell_of(double v) const { return cellIndex(v / cell_); }
  const std::vector<Eigen::Vector2d>& pts_;
  double cell_;
  std::unordered_map<int64_t, std::vector<size_t>> cells_;
};

void compareInto(const JoinSide& from, const JoinSide& to, double zone_m, double gate_m,
                 TrunkAgreement* out) {
  const PointGrid origins(to.origins, zone_m), trunks(to.trunks, gate_m);
  for (const Eigen::Vector2d& p : from.trunks) {
    if (!origins.anyWithin(p, zone_m)) continue;
    ++out->compared;
    if (trunks.anyWithin(p, gate_m)) ++out->matched;
  }
}

}  // namespace

TrunkAgreement trunkAgreement(const JoinSide& a, const JoinSide& b, double zone_m, double gate_m) {
  TrunkAgreement out;
  compareInto(a, b, zone_m, gate_m, &out);
  compareInto(b, a, zone_m, gate_m, &out);
  return out;
}

}  // namespace dtif
