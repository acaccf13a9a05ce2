// Runs dtif/LoopClosureNodelet as a plain node (same class as the nodelet): `rosrun dtif
// loop_closure_node`. Private parameters, remappings and the namespace work as for the nodelet.
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "loop_closure");
  nodelet::Loader loader(false);  // no manager services: this process hosts one nodelet
  const nodelet::M_string remappings = ros::names::getRemappings();
  const nodelet::V_string my_argv;
  if (!loader.load(ros::this_node::getName(), "dtif/LoopClosureNodelet", remappings, my_argv)) {
    ROS_FATAL("could not start dtif/LoopClosureNodelet (see the error above)");
    return 1;
  }
  ros::spin();
  return 0;
}
