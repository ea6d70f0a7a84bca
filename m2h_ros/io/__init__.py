"""Files: rosbag2/MCAP bags through rosbags, message definitions, audio files."""
