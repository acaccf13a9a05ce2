// Runs the `dtif` binary as a user would (the tool tests).
#pragma once

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <string>

#include "dtif_test/test_config.h"

namespace dtif::test {

struct ToolRun {
  int status = -1;  ///< exit status
  std::string out;  ///< stdout and stderr
};

/// Runs `dtif <args>` (args as shell words) and collects its exit status and output.
inline ToolRun runTool(const std::string& args) {
  ToolRun r;
  const std::string cmd = std::string(DTIF_TOOL) + " " + args + " 2>&1";
  FILE* pipe = popen(cmd.c_str(), "r");
  if (!pipe) return r;
  std::array<char, 4096> buf;
  size_t n = 0;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.out.append(buf.data(), n);
  const int st = pclose(pipe);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

}  // namespace dtif::test
