"""The ROS shell: conversions between core types and messages, QoS profiles, parameters."""
