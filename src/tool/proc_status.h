// This process's memory from /proc/self/status, for the benchmarks' reports.
#pragma once

#include <fstream>
#include <string>

namespace dtif {

/// VmRSS or VmHWM of this process [MiB] (0 when unreadable).
inline double procMiB(const char* key) {
  std::ifstream is("/proc/self/status");
  std::string k;
  double kb = 0.0;
  while (is >> k) {
    if (k == std::string(key) + ":") {
      is >> kb;
      return kb / 1024.0;
    }
    is.ignore(1 << 12, '\n');
  }
  return 0.0;
}

}  // namespace dtif
