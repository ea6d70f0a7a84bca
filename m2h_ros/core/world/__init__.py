"""The simulated world: scenes, navigation grid, binaural acoustics, camera, episodes, environment."""
