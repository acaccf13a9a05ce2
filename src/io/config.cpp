// YAML form of dtif's parameters: one section per component; every key must be known.
#include "dtif/io/config.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>

#include "dtif/core/file_io.h"

namespace dtif {

namespace {

/// Reads the fields a params struct visits from a YAML map, remembering which keys it used.
class YamlReader {
 public:
  YamlReader(const YAML::Node& node, std::string where) : node_(node), where_(std::move(where)) {}

  template <class T>
  void operator()(const char* name, T& value) {
    used_.insert(name);
    const YAML::Node v = node_[name];
    if (!v) return;
    if (!v.IsScalar()) throw ParamError(where_ + "." + name + ": expected a scalar value");
    try {
      if constexpr (std::is_same_v<T, bool>) {
        value = v.as<bool>();
      } else if constexpr (std::is_integral_v<T>) {
        // Reject 2.5 for an integer instead of truncating it, and 2e34 before the cast (out of
        // range is undefined behaviour; fuzz_config found it).
        const double d = v.as<double>();
        const double hi = std::ldexp(1.0, std::numeric_limits<T>::digits);
        const double lo = std::is_signed_v<T> ? -hi : 0.0;
        if (!(d >= lo && d < hi) || d != std::floor(d)) throw YAML::BadConversion(v.Mark());
        value = static_cast<T>(d);
      } else {
        value = v.as<T>();
      }
    } catch (const YAML::BadConversion&) {
      throw ParamError(where_ + "." + name + ": cannot read '" + v.Scalar() + "' as " +
                       typeName<T>());
    }
  }

  /// Throws on the first key of the map that no field declared.
  void rejectUnknown() const {
    for (const auto& kv : node_) {
      if (!kv.first.IsScalar()) throw ParamError(where_ + ": a key is not a name");
      const std::string key = kv.first.as<std::string>();
      if (!used_.count(key)) throw ParamError(where_ + ": unknown parameter '" + key + "'");
    }
  }

 private:
  template <class T>
  static const char* typeName() {
    if constexpr (std::is_same_v<T, bool>) return "a boolean";
    if constexpr (std::is_integral_v<T>) return "an integer";
    if constexpr (std::is_floating_point_v<T>) return "a number";
    return "a string";
  }

  const YAML::Node& node_;
  std::string where_;
  std::set<std::string> used_;
};

/// Writes visited fields as YAML key: value lines.
class YamlWriter {
 public:
  explicit YamlWriter(YAML::Emitter& out) : out_(out) {}
  template <class T>
  void operator()(const char* name, T& value) {
    out_ << YAML::Key << name << YAML::Value << value;
  }

 private:
  YAML::Emitter& out_;
};

template <class Params>
void readSection(const YAML::Node& root, const char* section, const std::string& file, Params* p) {
  const YAML::Node node = root[section];
  if (!node) return;
  if (node.IsNull()) return;  // an empty section keeps the defaults
  if (!node.IsMap()) throw ParamError(file + ": section '" + section + "' must be a map");
  YamlReader reader(node, file + ": " + section);
  p->visit(reader);
  reader.rejectUnknown();
}

template <class Params>
void writeSection(YAML::Emitter& out, const char* section, Params p) {
  out << YAML::Key << section << YAML::Value << YAML::BeginMap;
  YamlWriter w(out);
  p.visit(w);
  out << YAML::EndMap;
}

}  // namespace

std::string DtifParams::validate() const {
  std::string out;
  auto add = [&out](const char* section, const std::string& msg) {
    if (!msg.empty()) out += std::string(section) + ": " + msg + "\n";
  };
  add("trunk_extraction", trunk_extraction.validate());
  add("levelling", levelling.validate());
  add("descriptor", descriptor.validate());
  add("multi_submap", multi_submap.validate());
  add("matcher", loop.matcher.validate());
  add("pose", loop.pose.validate());
  add("verification", loop.verification.validate());
  add("database", loop.database.validate());
  add("merge", merge.validate());
  if (!out.empty()) out.pop_back();
  return out;
}

void loadParamsYaml(const std::string& path, DtifParams* p) {
  YAML::Node root;
  // A folder read as "basic_filebuf::underflow", a FIFO blocked: checked before opening.
  constexpr uint64_t kMaxYamlBytes = uint64_t{16} << 20;
  const std::string problem = regularFileProblem(path, kMaxYamlBytes);
  if (!problem.empty()) throw ParamError(path + ": cannot open parameter file: " + problem);
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw ParamError(path + ": cannot open parameter file");
  } catch (const YAML::Exception& e) {
    throw ParamError(path + ": malformed YAML: " + e.msg + " (line " +
                     std::to_string(e.mark.line + 1) + ")");
  } catch (const std::exception& e) {
    throw ParamError(path + ": cannot read parameter file: " + e.what());
  }
  if (root.IsNull()) return;  // an empty file changes nothing
  if (!root.IsMap()) throw ParamError(path + ": expected a map of parameter sections");
  static const std::set<std::string> kSections = {
      "trunk_extraction", "levelling", "descriptor", "multi_submap", "matcher", "pose",
      "verification",     "database",  "merge",      "stems"};
  for (const auto& kv : root) {
    if (!kv.first.IsScalar()) throw ParamError(path + ": a section name is not a name");
    const std::string key = kv.first.as<std::string>();
    if (!kSections.count(key)) throw ParamError(path + ": unknown section '" + key + "'");
  }
  DtifParams next = *p;
  readSection(root, "trunk_extraction", path, &next.trunk_extraction);
  readSection(root, "levelling", path, &next.levelling);
  readSection(root, "descriptor", path, &next.descriptor);
  readSection(root, "multi_submap", path, &next.multi_submap);
  readSection(root, "matcher", path, &next.loop.matcher);
  readSection(root, "pose", path, &next.loop.pose);
  readSection(root, "verification", path, &next.loop.verification);
  readSection(root, "database", path, &next.loop.database);
  readSection(root, "merge", path, &next.merge);
  readSection(root, "stems", path, &next.merge.stems);
  const std::string problems = next.validate();
  if (!problems.empty()) throw ParamError(path + ": invalid parameters: " + problems);
  *p = next;
}

std::string paramsToYaml(const DtifParams& p) {
  YAML::Emitter out;
  out.SetDoublePrecision(12);
  out << YAML::BeginMap;
  writeSection(out, "trunk_extraction", p.trunk_extraction);
  writeSection(out, "levelling", p.levelling);
  writeSection(out, "descriptor", p.descriptor);
  writeSection(out, "multi_submap", p.multi_submap);
  writeSection(out, "matcher", p.loop.matcher);
  writeSection(out, "pose", p.loop.pose);
  writeSection(out, "verification", p.loop.verification);
  writeSection(out, "database", p.loop.database);
  writeSection(out, "merge", p.merge);
  writeSection(out, "stems", p.merge.stems);
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace dtif
