// Message -> core conversions of the nodelets (src/ros/conversions.cpp), on messages
// deserialised from the input by ros::serialization as they arrive from the wire: the first
// byte picks TrunkDescriptor, LoopClosure or PointCloud2.
#include <ros/serialization.h>

#include <type_traits>

#include "dtif/core/descriptor/validation.h"
#include "dtif/ros/conversions.h"
#include "dtif/ros/msgs.h"

namespace {

// roscpp's deserializer resizes a vector to its serialized count before it reads the elements
// (ros/serialization.h), so a count of 4e9 in a short message allocates gigabytes inside roscpp
// itself: upstream behaviour, not dtif's conversions, which this target is for. This stream
// refuses any uint32 larger than the bytes left (every count; also large stamps, which the
// conversions do not read).
class BoundedIStream : public ros::serialization::IStream {
 public:
  using IStream::IStream;
  template <typename T>
  void next(T& t) {
    ros::serialization::deserialize(*this, t);
    if constexpr (std::is_same_v<T, uint32_t>) {
      if (t > getLength()) throw ros::serialization::StreamOverrunException("count beyond input");
    }
  }
  template <typename T>
  BoundedIStream& operator>>(T& t) {
    next(t);
    return *this;
  }
};

template <class Msg>
bool deserialise(const uint8_t* data, size_t size, Msg* msg) {
  try {
    BoundedIStream in(const_cast<uint8_t*>(data), static_cast<uint32_t>(size));
    ros::serialization::deserialize(in, *msg);
  } catch (const ros::Exception&) {  // runs past the end: the transport drops such messages
    return false;
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0 || size > (1u << 20)) return 0;
  const int which = data[0] % 3;
  ++data, --size;
  namespace rg = dtif::ros_glue;
  if (which == 0) {
    dtif::TrunkDescriptor msg;
    if (!deserialise(data, size, &msg)) return 0;
    dtif::Descriptor d;
    dtif::Pose T;
    rg::fromMsg(msg, dtif::loosestDescriptorParams(), &d, &T);
  } else if (which == 1) {
    dtif::LoopClosure msg;
    if (!deserialise(data, size, &msg)) return 0;
    dtif::Loop lc;
    rg::fromMsg(msg, &lc);
  } else {
    sensor_msgs::PointCloud2 msg;
    if (!deserialise(data, size, &msg)) return 0;
    dtif::Cloud cloud;
    rg::fromMsg(msg, &cloud);
  }
  return 0;
}
