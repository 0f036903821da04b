"""The ROS layer: the only subpackage that imports rospy, actionlib, rosbag, tf2 or message modules."""
