// The descriptor wire format (decodeDescriptor): a descriptor or a runtime_error; an accepted
// one re-encodes.
#include <stdexcept>

#include "dtif/core/descriptor/descriptor.h"
#include "dtif/core/descriptor/validation.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::vector<uint8_t> bytes(data, data + size);
  try {
    const dtif::Descriptor d = dtif::decodeDescriptor(bytes, dtif::loosestDescriptorParams());
    dtif::encodeDescriptor(d);  // what was accepted can be written
  } catch (const std::runtime_error&) {
  }
  return 0;
}
