# Run by the build (target dtif_layering, before any library compiles): fails when a part of
# dtif includes a part above it or ROS where ROS is not allowed. Debian installs ROS headers in
# /usr/include, so the compiler alone would not notice a ROS header in the core.
#   cmake -DROOT=<repository> -P scripts/check_layering.cmake
set(ros "ros/|nodelet/|pluginlib/|rosbag/|tf2|tf2_ros/|tf2_eigen/|pcl_conversions/|std_msgs/|sensor_msgs/|geometry_msgs/|nav_msgs/|visualization_msgs/|dtif/[A-Z]")
# folder (in src/ and include/dtif/) -> what it must not include
set(rules
  "core|${ros}|dtif/(io|eval|sim|bag|baselines|ros|tool)/|yaml-cpp/|nlohmann/|png\\.h"
  "io|${ros}|dtif/(eval|sim|bag|baselines|ros|tool)/"
  "eval|${ros}|dtif/(sim|bag|baselines|ros|tool)/"
  "sim|${ros}|dtif/(eval|bag|baselines|ros|tool)/"
  "baselines|${ros}|dtif/(sim|bag|ros|tool)/"
  "bag|dtif/(eval|baselines|ros|tool)/"
  "ros|dtif/(eval|sim|bag|baselines|tool)/")
set(problems "")
foreach(rule ${rules})
  string(REPLACE "|" ";" parts "${rule}")
  list(POP_FRONT parts folder)
  string(REPLACE ";" "|" forbidden "${parts}")
  file(GLOB_RECURSE files ${ROOT}/src/${folder}/*.h ${ROOT}/src/${folder}/*.cpp
       ${ROOT}/include/dtif/${folder}/*.h)
  foreach(f ${files})
    file(STRINGS ${f} hits REGEX "^[ \t]*#[ \t]*include[ \t]*[<\"](${forbidden})")
    foreach(hit ${hits})
      file(RELATIVE_PATH rel ${ROOT} ${f})
      string(APPEND problems "\n  ${rel}: ${hit}")
    endforeach()
  endforeach()
endforeach()
if(problems)
  message(FATAL_ERROR "dtif layering: these includes point up or bring ROS where it is not allowed "
                      "(docs/design.md, Architecture):${problems}")
endif()
