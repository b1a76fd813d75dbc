// Standalone executable hosting the same Long3rNodelet class, for users who
// do not run a nodelet manager.
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "long3r");
  nodelet::Loader loader;
  nodelet::M_string remappings(ros::names::getRemappings());
  nodelet::V_string my_argv(argv + 1, argv + argc);
  if (!loader.load(ros::this_node::getName(), "long3r_ros/Long3rNodelet", remappings, my_argv)) {
    ROS_FATAL("could not load long3r_ros/Long3rNodelet; see the errors above");
    return 1;
  }
  ros::spin();
  return 0;
}
