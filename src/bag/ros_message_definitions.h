// MD5 sums and full definitions of the ROS messages RosbagWriter serialises, copied from the
// generated headers installed by Debian (/usr/include/sensor_msgs/PointCloud2.h,
// nav_msgs/Odometry.h, tf2_msgs/TFMessage.h: ros::message_traits::MD5Sum and Definition), so
// the ROS-free core needs no ROS header. rosbag_writer_test checks them against those traits.
// Internal to src/core/rosbag_writer.cpp.
#pragma once

// Definitions embed those of the messages they use, each after a separator line (as
// genmsg writes them); the blocks used by several messages are written once here.
#define DTIF_MSG_DEF_HEADER                                                                     \
  "================================================================================\n"          \
  "MSG: std_msgs/Header\n"                                                                      \
  "# Standard metadata for higher-level stamped data types.\n"                                  \
  "# This is generally used to communicate timestamped data \n"                                 \
  "# in a particular coordinate frame.\n"                                                       \
  "# \n"                                                                                        \
  "# sequence ID: consecutively increasing ID \n"                                               \
  "uint32 seq\n"                                                                                \
  "#Two-integer timestamp that is expressed as:\n"                                              \
  "# * stamp.sec: seconds (stamp_secs) since epoch (in Python the variable is called 'secs')\n" \
  "# * stamp.nsec: nanoseconds since stamp_secs (in Python the variable is called 'nsecs')\n"   \
  "# time-handling sugar is provided by the client library\n"                                   \
  "time stamp\n"                                                                                \
  "#Frame this data is associated with\n"                                                       \
  "string frame_id\n"
#define DTIF_MSG_DEF_VECTOR3                                                           \
  "================================================================================\n" \
  "MSG: geometry_msgs/Vector3\n"                                                       \
  "# This represents a vector in free space. \n"                                       \
  "# It is only meant to represent a direction. Therefore, it does not\n"              \
  "# make sense to apply a translation to it (e.g., when applying a \n"                \
  "# generic rigid transformation to a Vector3, tf2 will only apply the\n"             \
  "# rotation). If you want your data to be translatable too, use the\n"               \
  "# geometry_msgs/Point message instead.\n"                                           \
  "\n"                                                                                 \
  "float64 x\n"                                                                        \
  "float64 y\n"                                                                        \
  "float64 z\n"
#define DTIF_MSG_DEF_QUATERNION                                                        \
  "================================================================================\n" \
  "MSG: geometry_msgs/Quaternion\n"                                                    \
  "# This represents an orientation in free space in quaternion form.\n"               \
  "\n"                                                                                 \
  "float64 x\n"                                                                        \
  "float64 y\n"                                                                        \
  "float64 z\n"                                                                        \
  "float64 w\n"

// Literal blocks joined by macros, one per line: not for clang-format to reflow.
// clang-format off
namespace dtif::bag::defs {

// sensor_msgs/PointCloud2
constexpr char kPointCloud2Type[] = "sensor_msgs/PointCloud2";
constexpr char kPointCloud2Md5[] = "1158d486dd51d683ce2f1be655c3c181";
constexpr char kPointCloud2Definition[] =
    "# This message holds a collection of N-dimensional points, which may\n"
    "# contain additional information such as normals, intensity, etc. The\n"
    "# point data is stored as a binary blob, its layout described by the\n"
    "# contents of the \"fields\" array.\n"
    "\n"
    "# The point cloud data may be organized 2d (image-like) or 1d\n"
    "# (unordered). Point clouds organized as 2d images may be produced by\n"
    "# camera depth sensors such as stereo or time-of-flight.\n"
    "\n"
    "# Time of sensor data acquisition, and the coordinate frame ID (for 3d\n"
    "# points).\n"
    "Header header\n"
    "\n"
    "# 2D structure of the point cloud. If the cloud is unordered, height is\n"
    "# 1 and width is the length of the point cloud.\n"
    "uint32 height\n"
    "uint32 width\n"
    "\n"
    "# Describes the channels and their layout in the binary data blob.\n"
    "PointField[] fields\n"
    "\n"
    "bool    is_bigendian # Is this data bigendian?\n"
    "uint32  point_step   # Length of a point in bytes\n"
    "uint32  row_step     # Length of a row in bytes\n"
    "uint8[] data         # Actual point data, size is (row_step*height)\n"
    "\n"
    "bool is_dense        # True if there are no invalid points\n"
    "\n"
    DTIF_MSG_DEF_HEADER
    "\n"
    "================================================================================\n"
    "MSG: sensor_msgs/PointField\n"
    "# This message holds the description of one point entry in the\n"
    "# PointCloud2 message format.\n"
    "uint8 INT8    = 1\n"
    "uint8 UINT8   = 2\n"
    "uint8 INT16   = 3\n"
    "uint8 UINT16  = 4\n"
    "uint8 INT32   = 5\n"
    "uint8 UINT32  = 6\n"
    "uint8 FLOAT32 = 7\n"
    "uint8 FLOAT64 = 8\n"
    "\n"
    "string name      # Name of field\n"
    "uint32 offset    # Offset from start of point struct\n"
    "uint8  datatype  # Datatype enumeration, see above\n"
    "uint32 count     # How many elements in the field\n";

// nav_msgs/Odometry
constexpr char kOdometryType[] = "nav_msgs/Odometry";
constexpr char kOdometryMd5[] = "cd5e73d190d741a2f92e81eda573aca7";
constexpr char kOdometryDefinition[] =
    "# This represents an estimate of a position and velocity in free space.  \n"
    "# The pose in this message should be specified in the coordinate frame given by "
    "header.frame_id.\n"
    "# The twist in this message should be specified in the coordinate frame given by the "
    "child_frame_id\n"
    "Header header\n"
    "string child_frame_id\n"
    "geometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist\n"
    "\n"
    DTIF_MSG_DEF_HEADER
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/PoseWithCovariance\n"
    "# This represents a pose in free space with uncertainty.\n"
    "\n"
    "Pose pose\n"
    "\n"
    "# Row-major representation of the 6x6 covariance matrix\n"
    "# The orientation parameters use a fixed-axis representation.\n"
    "# In order, the parameters are:\n"
    "# (x, y, z, rotation about X axis, rotation about Y axis, rotation about Z axis)\n"
    "float64[36] covariance\n"
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/Pose\n"
    "# A representation of pose in free space, composed of position and orientation. \n"
    "Point position\n"
    "Quaternion orientation\n"
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/Point\n"
    "# This contains the position of a point in free space\n"
    "float64 x\n"
    "float64 y\n"
    "float64 z\n"
    "\n"
    DTIF_MSG_DEF_QUATERNION
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/TwistWithCovariance\n"
    "# This expresses velocity in free space with uncertainty.\n"
    "\n"
    "Twist twist\n"
    "\n"
    "# Row-major representation of the 6x6 covariance matrix\n"
    "# The orientation parameters use a fixed-axis representation.\n"
    "# In order, the parameters are:\n"
    "# (x, y, z, rotation about X axis, rotation about Y axis, rotation about Z axis)\n"
    "float64[36] covariance\n"
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/Twist\n"
    "# This expresses velocity in free space broken into its linear and angular parts.\n"
    "Vector3  linear\n"
    "Vector3  angular\n"
    "\n"
    DTIF_MSG_DEF_VECTOR3;

// tf2_msgs/TFMessage
constexpr char kTfMessageType[] = "tf2_msgs/TFMessage";
constexpr char kTfMessageMd5[] = "94810edda583a504dfda3829e70d7eec";
constexpr char kTfMessageDefinition[] =
    "geometry_msgs/TransformStamped[] transforms\n"
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/TransformStamped\n"
    "# This expresses a transform from coordinate frame header.frame_id\n"
    "# to the coordinate frame child_frame_id\n"
    "#\n"
    "# This message is mostly used by the \n"
    "# <a href=\"http://wiki.ros.org/tf\">tf</a> package. \n"
    "# See its documentation for more information.\n"
    "\n"
    "Header header\n"
    "string child_frame_id # the frame id of the child frame\n"
    "Transform transform\n"
    "\n"
    DTIF_MSG_DEF_HEADER
    "\n"
    "================================================================================\n"
    "MSG: geometry_msgs/Transform\n"
    "# This represents the transform between two coordinate frames in free space.\n"
    "\n"
    "Vector3 translation\n"
    "Quaternion rotation\n"
    "\n"
    DTIF_MSG_DEF_VECTOR3
    DTIF_MSG_DEF_QUATERNION;

}  // namespace dtif::bag::defs
// clang-format on

#undef DTIF_MSG_DEF_HEADER
#undef DTIF_MSG_DEF_VECTOR3
#undef DTIF_MSG_DEF_QUATERNION
