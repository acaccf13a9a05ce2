// dtif: the offline command-line tool (simulate, extract, register, eval, merge, score, bench).
// Exit status: 0 success (and --help, --version), 1 runtime error (`dtif <cmd>: <file>:
// <problem>`), 2 bad usage (one line saying what is wrong, then where to find the usage).
#include <CLI/CLI.hpp>
#include <exception>
#include <iostream>
#include <string>

#include "commands.h"
#include "options.h"

namespace {

/// The subcommand the command line named ("" when none was recognised).
std::string commandOf(const CLI::App& app) {
  const auto subs = app.get_subcommands();
  return subs.empty() ? std::string() : subs.front()->get_name();
}

/// Help and version go to stdout (exit 0); anything else is a one-line usage error (exit 2).
int reportParseError(const CLI::App& app, const CLI::ParseError& e, int argc, char** argv) {
  if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);
  const std::string cmd = commandOf(app);
  if (cmd.empty() && argc >= 2) {
    // Only --help and --version come before the command: anything else names what is wrong.
    std::cerr << "dtif: unknown " << (argv[1][0] == '-' ? "option" : "command") << " '" << argv[1]
              << "'\n";
  } else {
    std::cerr << "dtif" << (cmd.empty() ? "" : " " + cmd) << ": " << e.what() << "\n";
  }
  std::cerr << "Run 'dtif" << (cmd.empty() ? "" : " " + cmd) << " --help' for the usage.\n";
  return 2;
}

int runCommand(const std::string& cmd, const dtif::tool::CommandLine& cl) {
  if (cmd == "simulate") return dtif::tool::runSimulate(cl.simulate);
  if (cmd == "extract") return dtif::tool::runExtract(cl.extract);
  if (cmd == "register") return dtif::tool::runRegister(cl.reg);
  if (cmd == "eval") return dtif::tool::runEval(cl.eval);
  if (cmd == "merge") return dtif::tool::runMerge(cl.merge);
  if (cmd == "score") return dtif::tool::runScore(cl.score);
  return dtif::tool::runBench(cl.bench);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app(
      "dtif: forest LiDAR loop closure from tree-trunk Delaunay descriptors, offline tool.\n"
      "Run 'dtif <command> --help' for the options of a command.",
      "dtif");
  app.set_version_flag("--version", std::string("dtif ") + DTIF_VERSION,
                       "print the version (package.xml) and exit");
  dtif::tool::CommandLine cl;
  dtif::tool::addCommands(&app, &cl);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return reportParseError(app, e, argc, argv);
  }
  const std::string cmd = commandOf(app);
  try {
    return runCommand(cmd, cl);
  } catch (const std::exception& e) {
    std::cerr << "dtif " << cmd << ": " << e.what() << "\n";
    return 1;
  }
}
