"""One module per ROS node; wiring only."""
