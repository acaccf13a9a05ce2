// Subcommands of the `dtif` tool. Each returns the process exit status (0 only on success)
// and prints one-line errors naming the file and the problem.
#pragma once

#include <string>
#include <vector>

#include "dtif/eval/evaluation.h"
#include "dtif/io/config.h"

namespace dtif::tool {

using Args = std::vector<std::string>;

int runSimulate(const Args& args);
int runExtract(const Args& args);
int runRegister(const Args& args);
int runEval(const Args& args);
int runBench(const Args& args);
int runScore(const Args& args);

/// results.csv, summary.json, table.md and params.yaml into folder out (created when missing).
void writeEvalFiles(const std::string& out, const EvalResult& res, const std::string& table,
                    const DtifParams& params);

/// Thrown for bad command-line usage; main() prints it with the usage line.
struct UsageError {
  std::string message;
};

}  // namespace dtif::tool
