// Subcommands of the `dtif` tool. Each returns the process exit status (0 only on success)
// and prints one-line errors naming the file and the problem.
#pragma once

#include <string>
#include <vector>

namespace dtif::tool {

using Args = std::vector<std::string>;

int runSimulate(const Args& args);
int runExtract(const Args& args);
int runRegister(const Args& args);
int runEval(const Args& args);
int runBench(const Args& args);

/// Thrown for bad command-line usage; main() prints it with the usage line.
struct UsageError {
  std::string message;
};

}  // namespace dtif::tool
