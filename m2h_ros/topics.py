"""Topic names of the pipeline (relative, so a namespace or remapping moves them; the ground truth is
absolute under /ground_truth, where only the evaluator subscribes). ROS-free: replay scoring reads
bags by these names too."""

AUDIO = "audio"  # m2h_msgs/BinauralAudio: the binaural mixture of a step (sim)
RGB = "camera/rgb/image_raw"  # sensor_msgs/Image rgb8 (sim)
DEPTH = "camera/depth/image_raw"  # sensor_msgs/Image 32FC1, metres (sim)
CAMERA_INFO = "camera/rgb/camera_info"  # sensor_msgs/CameraInfo, same stamp as the images (sim)
ODOM = "odom"  # nav_msgs/Odometry: pose of the step (sim)
AGENT_POSE = "agent_pose"  # m2h_msgs/AgentPose: the same pose on the navigation grid (sim)
EPISODE = "episode"  # m2h_msgs/EpisodeInfo, latched (sim)
GROUND_TRUTH = "/ground_truth/target"  # m2h_msgs/GroundTruth (sim -> evaluator only)
SEPARATED_BINAURAL = "separator/binaural"  # m2h_msgs/Spectrogram SEPARATED_BINAURAL (separator)
MONAURAL = "separator/monaural"  # m2h_msgs/Spectrogram MONAURAL_ESTIMATE (separator)
REFINED = "separator/refined"  # m2h_msgs/Spectrogram REFINED (separator)
SEPARATED_AUDIO = "separator/audio"  # m2h_msgs/BinauralAudio, 2 channels (binaural) or 1: audio for a listener
COMMAND = "cmd"  # m2h_msgs/MotionCommand (controller)
CMD_VEL = "cmd_vel"  # geometry_msgs/TwistStamped (or Twist): the velocity a robot base is sent (base)
MOTION_RESULT = "motion_result"  # m2h_msgs/MotionResult: how the base carried out a command (base)
# Robot mode: the microphones' continuous frames, and what the episode driver stamps with each step.
MIC_AUDIO = "mic/audio"  # m2h_msgs/BinauralAudio: every captured frame (capture_node, remapped)
STEP_ODOM = "step/odom"  # nav_msgs/Odometry: the robot's odometry at a step's frame (episode driver)
STEP_RGB = "step/camera/rgb/image_raw"  # sensor_msgs/Image: the robot's RGB at a step (episode driver)
STEP_DEPTH = "step/camera/depth/image_raw"  # sensor_msgs/Image: its depth at a step (episode driver)
STEP_SCORE = "scores/step"  # m2h_msgs/StepScore (evaluator)
EPISODE_SCORE = "scores/episode"  # m2h_msgs/EpisodeScore (evaluator)
# Seeing and hearing a run (rviz, Foxglove).
TF, TF_STATIC = "/tf", "/tf_static"  # tf2_msgs/TFMessage: the robot's frames (sim where tf2_msgs is installed, else recorder)
MAP = "map"  # nav_msgs/OccupancyGrid, latched: the episode's floor plan (sim)
PATH = "path"  # visualization_msgs/MarkerArray: where the robot has been this episode (sim)
SOURCES = "/ground_truth/sources"  # visualization_msgs/MarkerArray: target and distractors (sim -> ground truth)
MIXTURE_IMAGE = "spectrogram/mixture"  # sensor_msgs/Image 32FC1, dB: the mixture, ears averaged (separator)
BINAURAL_IMAGE = "spectrogram/separated_binaural"  # the same for f^B's separated binaural (separator)
MONAURAL_IMAGE = "spectrogram/monaural"  # f^M's monaural estimate (separator)
REFINED_IMAGE = "spectrogram/refined"  # f^R's refined estimate (separator)
TARGET_IMAGE = "/ground_truth/spectrogram/target"  # the target's dry clip (evaluator)

# The pipeline's state: transient-local, the last message is what a late joiner needs. Its step streams
# are transient-local too (a deep history, for lag), and discovery does not tell a publisher's depth.
STATE = (EPISODE, MAP, TF_STATIC)
