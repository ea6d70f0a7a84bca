"""ROS-free core: scenes, acoustics, sounds, episodes, environment, spectrograms, metrics."""
