// Runs dtif/TrunkExtractionNodelet as a plain node (same class as the nodelet): `rosrun dtif
// trunk_extraction_node`. Private parameters, remappings and the namespace work as for the nodelet.
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "trunk_extraction");
  nodelet::Loader loader(false);  // no manager services: this process hosts one nodelet
  const nodelet::M_string remappings = ros::names::getRemappings();
  const nodelet::V_string my_argv;
  if (!loader.load(ros::this_node::getName(), "dtif/TrunkExtractionNodelet", remappings, my_argv)) {
    ROS_FATAL("could not start dtif/TrunkExtractionNodelet (see the error above)");
    return 1;
  }
  ros::spin();
  return 0;
}
