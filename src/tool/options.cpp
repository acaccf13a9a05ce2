#include "options.h"

namespace dtif::tool {

Options parseOptions(const Args& args, const std::set<std::string>& value_keys,
                     const std::set<std::string>& flag_keys) {
  Options o;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a.rfind("--", 0) != 0 || a == "--") {
      o.positional.push_back(a);
      continue;
    }
    const std::string key = a.substr(2);
    if (flag_keys.count(key)) {
      o.flags.insert(key);
    } else if (value_keys.count(key)) {
      if (i + 1 >= args.size()) throw UsageError{"option " + a + " needs a value"};
      o.values[key].push_back(args[++i]);
    } else {
      throw UsageError{"unknown option " + a};
    }
  }
  return o;
}

DtifParams loadParams(const Options& opts) {
  DtifParams p;
  const auto it = opts.values.find("config");
  if (it != opts.values.end()) {
    for (const auto& file : it->second) loadParamsYaml(file, &p);
  }
  return p;
}

}  // namespace dtif::tool
