// Database files (readDatabaseFile, the loop-closure nodelet's load service).
#include <stdexcept>

#include "dtif/core/database/loop_detector.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = dtif::fuzz::writeInput("db.bin", data, size);
  try {
    dtif::LoopDetector db{dtif::LoopDetectorParams{}};
    db.load(path);
    db.save(path);  // what was accepted can be written
  } catch (const std::runtime_error&) {
  }
  return 0;
}
