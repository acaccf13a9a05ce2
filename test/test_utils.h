// Small helpers shared by the core and glue tests.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <string>

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

/// An empty folder of this process under the system's temporary folder (removed first if it
/// exists); the process id keeps test runs on one machine out of each other's way.
inline std::filesystem::path freshTempDir(const std::string& name) {
  const std::filesystem::path p =
      std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p;
}

}  // namespace dtif::test
