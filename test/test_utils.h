// Small helpers shared by the core and glue tests.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <random>
#include <string>
#include <system_error>
#include <vector>

#include "dtif/core/types.h"

namespace dtif::test {

/// Pose from a translation and ZYX Euler angles (yaw about z, then pitch, then roll) [m, rad].
inline Pose makePose(double x, double y, double z, double roll, double pitch, double yaw) {
  Pose T = Pose::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

/// A vector of three random draws, one per statement: z first, then y, then x, the order gcc
/// evaluated `Eigen::Vector3d(dx(rng), dy(rng), dz(rng))` in, so the tests' data (and the
/// thresholds checked on them) are the same whatever the compiler.
template <class Dx, class Dy, class Dz>
Eigen::Vector3d randomVector(std::mt19937& rng, Dx& dx, Dy& dy, Dz& dz) {
  const double z = dz(rng);
  const double y = dy(rng);
  const double x = dx(rng);
  return {x, y, z};
}

/// The folders freshTempDir made, removed when the test process exits (a developer running
/// the tests all day would otherwise fill /tmp: one holds a 1 GB sparse file).
struct TempDirs {
  std::vector<std::filesystem::path> paths;
  ~TempDirs() {
    std::error_code ec;
    for (const std::filesystem::path& p : paths) std::filesystem::remove_all(p, ec);
  }
};
inline TempDirs& tempDirs() {
  static TempDirs dirs;
  return dirs;
}

/// An empty folder of this process under the system's temporary folder (removed first if it
/// exists, and when the process exits); the process id keeps test runs on one machine out of
/// each other's way.
inline std::filesystem::path freshTempDir(const std::string& name) {
  const std::filesystem::path p =
      std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  tempDirs().paths.push_back(p);
  return p;
}

}  // namespace dtif::test
