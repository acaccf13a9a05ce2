// The PCD reader (dtif extract, datasets): any bytes give a cloud or a DatasetError.
#include <pcl/console/print.h>

#include "dtif/io/dataset.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);  // PCL's own diagnostics
  const std::string path = dtif::fuzz::writeInput("cloud.pcd", data, size);
  try {
    dtif::loadPcd(path);
  } catch (const dtif::DatasetError&) {
  }
  return 0;
}
