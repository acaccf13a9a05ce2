// Parameter structs are visited field by field so that YAML files (core) and the ROS parameter
// server (glue) are read by the same code, and unknown keys can be detected.
#pragma once

#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace dtif {

/// Thrown for a bad parameter file or value; the message names the file/key and the problem.
class ParamError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Collects the names of a params struct's fields (used to reject unknown keys).
struct FieldNameCollector {
  std::vector<std::string> names;
  template <class T>
  void operator()(const char* name, T& /*value*/) {
    names.emplace_back(name);
  }
};

/// Returns the field names a params struct declares through its visit() member.
template <class Params>
std::vector<std::string> fieldNames() {
  Params p;
  FieldNameCollector c;
  p.visit(c);
  return c.names;
}

}  // namespace dtif
