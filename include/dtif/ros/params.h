// Reading the core's parameter structs from the ROS parameter server through their visit()
// members, so each default lives only in the struct, and rejecting keys that no struct declares.
#pragma once

#include <ros/node_handle.h>

#include <set>
#include <string>
#include <vector>

#include "dtif/core/params.h"

namespace dtif {
namespace ros_glue {

/// Keys `<section>/<field>` (or `<field>` for an empty section) a params struct declares.
template <class Params>
std::vector<std::string> declaredKeys(const std::string& section) {
  std::vector<std::string> keys;
  for (const std::string& f : fieldNames<Params>()) {
    keys.push_back(section.empty() ? f : section + "/" + f);
  }
  return keys;
}

/// Of all parameter names on the server (absolute), those under namespace ns that are not in
/// known, relative to ns and sorted. Pure; used by ParamReader and testable without a master.
std::vector<std::string> findUnknownKeys(const std::vector<std::string>& all_names,
                                         const std::string& ns, const std::set<std::string>& known);

/// Reads parameters below one namespace (normally a nodelet's private one) and remembers every
/// key it was asked about, so that checkNoUnknownKeys() can report the rest. Not thread-safe;
/// used once, in onInit().
class ParamReader {
 public:
  explicit ParamReader(const ros::NodeHandle& nh) : nh_(nh) {}

  /// Reads every field of a params struct from `<ns>/<section>/<field>` (or `<ns>/<field>` when
  /// section is empty). Missing keys keep the struct's value. Throws ParamError on a wrong type.
  template <class Params>
  void readSection(const std::string& section, Params* p) {
    Visitor v{this, section};
    p->visit(v);
  }

  /// Reads one value; missing keeps *value. Throws ParamError on a wrong type.
  void get(const std::string& key, bool* value);
  void get(const std::string& key, int* value);
  void get(const std::string& key, double* value);
  void get(const std::string& key, std::string* value);
  void get(const std::string& key, std::vector<std::string>* value);

  /// Every parameter under the namespace that was not read, as keys relative to it.
  std::vector<std::string> unknownKeys() const;
  /// Throws ParamError naming every unknown key.
  void checkNoUnknownKeys() const;

  const ros::NodeHandle& nodeHandle() const { return nh_; }

 private:
  struct Visitor {
    ParamReader* reader;
    std::string section;
    template <class T>
    void operator()(const char* name, T& value) {
      reader->get(section.empty() ? std::string(name) : section + "/" + name, &value);
    }
  };

  ros::NodeHandle nh_;
  std::set<std::string> used_;
};

}  // namespace ros_glue
}  // namespace dtif
