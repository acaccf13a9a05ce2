// The ground map's compressed encoding (inside descriptors and messages).
#include <stdexcept>

#include "dtif/core/extraction/ground_map.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const dtif::GroundMap m = dtif::decodeGroundMap(data, size);
    if (!m.empty()) dtif::encodeGroundMap(m);
  } catch (const std::runtime_error&) {
  }
  return 0;
}
