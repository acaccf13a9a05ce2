// dtif register <query> <candidate> [--config params.yaml]
// Inputs are PCD submaps or trunk-map CSVs (x,y,z,r; a field inventory is such a map).
#include <chrono>
#include <iomanip>
#include <iostream>
#include <memory>

#include "commands.h"
#include "dtif/core/database/loop_detector.h"
#include "dtif/core/descriptor/describe.h"
#include "dtif/core/timing.h"
#include "dtif/io/dataset.h"

namespace dtif::tool {

namespace {

bool endsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

/// A PCD submap gets its trunks and footprint extracted; a trunk map CSV has no footprint.
Descriptor loadDescriptor(const std::string& path, const SubmapKey& key, const DtifParams& params) {
  if (endsWith(path, ".pcd")) {
    return describeCloud(*loadPcd(path), key, params.trunk_extraction, params.descriptor);
  }
  if (!endsWith(path, ".csv")) {
    throw DatasetError(path + ": unknown input type (expected a .pcd submap or an x,y,z,r .csv)");
  }
  Descriptor d = buildDescriptor(readTrunkCsv(path), params.descriptor);
  d.robot = key.robot;
  d.submap_id = key.submap_id;
  d.stamp = key.stamp;
  return d;
}

}  // namespace

int runRegister(const RegisterArgs& a) {
  const DtifParams params = loadParams(a.configs);

  const auto t0 = std::chrono::steady_clock::now();
  auto q = std::make_shared<Descriptor>(loadDescriptor(a.query, {"query", 0, 0.0}, params));
  auto c = std::make_shared<Descriptor>(loadDescriptor(a.candidate, {"candidate", 1, 0.0}, params));
  const double desc_ms = msSince(t0);

  std::cout << "query:     " << a.query << ": " << q->trunks.size() << " trunks, "
            << q->triangles.size() << " faces\n"
            << "candidate: " << a.candidate << ": " << c->trunks.size() << " trunks, "
            << c->triangles.size() << " faces\n";
  for (const auto* d : {q.get(), c.get()}) {
    if (!d->valid) {
      std::cerr << "dtif register: " << (d == q.get() ? a.query : a.candidate)
                << ": descriptor excluded from retrieval: " << d->invalid_reason << "\n";
      return 1;
    }
  }

  LoopDetector detector(params.loop);
  detector.insert(c);
  QueryStats qs;
  const auto t1 = std::chrono::steady_clock::now();
  const auto loop = detector.query(*q, &qs);
  const double loop_ms = msSince(t1);
  std::cout << std::fixed << std::setprecision(3) << "time: descriptors " << desc_ms << " ms, loop "
            << loop_ms << " ms (solver " << qs.solver_ms << " ms)\n";
  // The pair once more through matchPair, for the verification's details and reason.
  PoseEstimate est;
  Verification ver;
  matchPair(*q, *c, params.loop, &est, &ver);
  if (!loop) {
    std::cout << "result: no verified registration (screened in: " << qs.screened_in
              << ", reached pose estimation: " << qs.matched << ")"
              << (qs.screened_in > 0 && !ver.reason().empty() ? ": " + ver.reason() : std::string())
              << "\n";
    return 1;
  }
  const Eigen::Vector3d t = loop->T_c_q.translation();
  const double yaw = std::atan2(loop->T_c_q.rotation()(1, 0), loop->T_c_q.rotation()(0, 0));
  std::cout << "result: registered, inliers " << loop->inliers << ", score " << loop->score << "\n"
            << "verification: overlap "
            << (ver.overlap >= 0.0 ? std::to_string(ver.overlap)
                                   : std::string("n/a (no footprint)"))
            << ", seen-base pairs " << ver.z_pairs << ", roll/pitch "
            << (ver.tilt_fitted ? "fitted" : "from gravity alignment") << "\n"
            << "T_c_q: x " << t.x() << " m, y " << t.y() << " m, z " << t.z() << " m, yaw "
            << yaw * 180.0 / M_PI << " deg\n"
            << std::setprecision(6) << loop->T_c_q.matrix() << "\n";
  return 0;
}

}  // namespace dtif::tool
