// Scene YAMLs (dtif simulate): loaded and validated only (simulating one is not bounded by the
// input's size).
#include "dtif/core/params.h"
#include "dtif/sim/simulator.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = dtif::fuzz::writeInput("scene.yaml", data, size);
  try {
    dtif::sim::loadSceneYaml(path);
  } catch (const dtif::ParamError&) {
  }
  return 0;
}
