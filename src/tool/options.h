// Minimal command-line parsing shared by the subcommands: positionals, `--key value`, flags.
#pragma once

#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "commands.h"
#include "dtif/io/config.h"

namespace dtif::tool {

struct Options {
  std::vector<std::string> positional;
  std::map<std::string, std::vector<std::string>> values;  ///< --key value (repeatable)
  std::set<std::string> flags;                             ///< --flag

  std::optional<std::string> get(const std::string& key) const {
    const auto it = values.find(key);
    if (it == values.end() || it->second.empty()) return std::nullopt;
    return it->second.back();
  }
  bool has(const std::string& flag) const { return flags.count(flag) > 0; }
};

/// Parses args; value_keys take one value, flag_keys none. Anything else is a UsageError.
Options parseOptions(const Args& args, const std::set<std::string>& value_keys,
                     const std::set<std::string>& flag_keys);

/// Default parameters overridden by every `--config` file given, in order.
DtifParams loadParams(const Options& opts);

}  // namespace dtif::tool
