// Subcommands of the `dtif` tool, given their parsed options (options.h, parsed in cli.cpp).
// Each returns the process exit status (0 only on success) and prints one-line errors naming
// the file and the problem; exceptions are reported by main() as `dtif <cmd>: <what>`.
#pragma once

#include <string>

#include "dtif/eval/evaluation.h"
#include "dtif/io/config.h"
#include "options.h"

namespace dtif::tool {

int runSimulate(const SimulateArgs& args);
int runExtract(const ExtractArgs& args);
int runRegister(const RegisterArgs& args);
int runEval(const EvalArgs& args);
int runMerge(const MergeArgs& args);
int runBench(const BenchArgs& args);
int runScore(const ScoreArgs& args);

/// results.csv, summary.json, table.md and params.yaml into folder out (created when missing).
void writeEvalFiles(const std::string& out, const EvalResult& res, const std::string& table,
                    const DtifParams& params);

}  // namespace dtif::tool
