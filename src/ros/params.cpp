#include "dtif/ros/params.h"

#include <ros/param.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace dtif {
namespace ros_glue {
namespace {

std::string typeName(const XmlRpc::XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeBoolean:
      return "bool";
    case XmlRpc::XmlRpcValue::TypeInt:
      return "int";
    case XmlRpc::XmlRpcValue::TypeDouble:
      return "double";
    case XmlRpc::XmlRpcValue::TypeString:
      return "string";
    case XmlRpc::XmlRpcValue::TypeArray:
      return "list";
    case XmlRpc::XmlRpcValue::TypeStruct:
      return "map";
    default:
      return "other";
  }
}

}  // namespace

#define DTIF_PARAM_FETCH(key)        \
  used_.insert(key);                 \
  XmlRpc::XmlRpcValue v;             \
  if (!nh_.getParam(key, v)) return; \
  const std::string full = nh_.resolveName(key);

void ParamReader::get(const std::string& key, bool* value) {
  DTIF_PARAM_FETCH(key)
  if (v.getType() != XmlRpc::XmlRpcValue::TypeBoolean) {
    throw ParamError(full + ": expected bool, got " + typeName(v));
  }
  *value = static_cast<bool>(v);
}

void ParamReader::get(const std::string& key, int* value) {
  DTIF_PARAM_FETCH(key)
  if (v.getType() != XmlRpc::XmlRpcValue::TypeInt) {
    throw ParamError(full + ": expected int, got " + typeName(v));
  }
  *value = static_cast<int>(v);
}

void ParamReader::get(const std::string& key, double* value) {
  DTIF_PARAM_FETCH(key)
  double d = 0.0;
  if (v.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
    d = static_cast<double>(v);
  } else if (v.getType() == XmlRpc::XmlRpcValue::TypeInt) {
    d = static_cast<int>(v);
  } else {
    throw ParamError(full + ": expected a number, got " + typeName(v));
  }
  if (!std::isfinite(d)) throw ParamError(full + ": not a finite number");
  *value = d;
}

void ParamReader::get(const std::string& key, std::string* value) {
  DTIF_PARAM_FETCH(key)
  if (v.getType() != XmlRpc::XmlRpcValue::TypeString) {
    throw ParamError(full + ": expected string, got " + typeName(v));
  }
  *value = static_cast<std::string>(v);
}

void ParamReader::get(const std::string& key, std::vector<std::string>* value) {
  DTIF_PARAM_FETCH(key)
  if (v.getType() != XmlRpc::XmlRpcValue::TypeArray) {
    throw ParamError(full + ": expected a list of strings, got " + typeName(v));
  }
  std::vector<std::string> out;
  for (int i = 0; i < v.size(); ++i) {
    if (v[i].getType() != XmlRpc::XmlRpcValue::TypeString) {
      throw ParamError(full + "[" + std::to_string(i) + "]: expected string, got " +
                       typeName(v[i]));
    }
    out.push_back(static_cast<std::string>(v[i]));
  }
  *value = out;
}

#undef DTIF_PARAM_FETCH

std::vector<std::string> findUnknownKeys(const std::vector<std::string>& all_names,
                                         const std::string& ns,
                                         const std::set<std::string>& known) {
  std::string prefix = ns;
  if (prefix.empty() || prefix.back() != '/') prefix += '/';
  std::vector<std::string> unknown;
  for (const std::string& name : all_names) {
    if (name.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string rel = name.substr(prefix.size());
    if (!rel.empty() && known.count(rel) == 0) unknown.push_back(rel);
  }
  std::sort(unknown.begin(), unknown.end());
  return unknown;
}

std::vector<std::string> ParamReader::unknownKeys() const {
  std::vector<std::string> all;
  if (!ros::param::getParamNames(all)) return {};
  return findUnknownKeys(all, nh_.getNamespace(), used_);
}

void ParamReader::checkNoUnknownKeys() const {
  const std::vector<std::string> unknown = unknownKeys();
  if (unknown.empty()) return;
  std::ostringstream os;
  os << "unknown parameter" << (unknown.size() > 1 ? "s" : "") << " under " << nh_.getNamespace()
     << ":";
  for (const std::string& k : unknown) os << " " << k;
  os << " (misspelled? see docs/ros.md)";
  throw ParamError(os.str());
}

}  // namespace ros_glue
}  // namespace dtif
