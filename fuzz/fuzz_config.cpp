// Parameter YAMLs (dtif --config, the nodelets' component files).
#include "dtif/io/config.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = dtif::fuzz::writeInput("params.yaml", data, size);
  try {
    dtif::DtifParams p;
    dtif::loadParamsYaml(path, &p);
  } catch (const dtif::ParamError&) {
  }
  return 0;
}
