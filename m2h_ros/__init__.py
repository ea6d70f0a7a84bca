"""m2h_ros: active audio-visual source separation (Move2Hear) as a ROS 2 Jazzy node suite."""

__version__ = "1.0.0"
