"""The configuration of each node, one frozen dataclass each; ``params/<node>.yaml`` holds the defaults."""

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from m2h_ros.agents.registry import CONTROLLER_NAMES
from m2h_ros import topics
from m2h_ros.config import DEVICES, Config, setting
from m2h_ros.core.audio.stft import AUDIO_CHANNELS, AUDIO_OUTPUTS
from m2h_ros.core.robot.base_motion import MotionLimits
from m2h_ros.core.world.acoustics import BACKENDS
from m2h_ros.core.world.hrtf import parse_head
from m2h_ros.core.world.worlds import parse_world_spec
from m2h_ros.errors import ConfigError
from m2h_ros.io.topic_selection import COMPRESSIONS, TopicSelection

TASKS = ("near_target", "far_target")
SOUND_SPLITS = ("heard", "unheard")
SCENE_SPLITS = ("train", "val", "test")
SIM_MODES = ("lockstep", "free_running")
TARGET_CLASSES = ("", "speech", "music")
PIPELINE_NODES = ("separator_node", "controller_node", "evaluator_node", "recorder_node")


def check_file(config: Config, name: str, path: str | Path | None, what: str) -> None:
    """ConfigError unless the file field ``name`` names (empty: none) exists: a missing one is named when
    the settings are read, before any node starts, not once every node is up and this one loads it."""
    if path and not Path(path).expanduser().is_file():
        raise ConfigError(f"{type(config).__name__}.{name} = {str(path)!r}: no such file ({what})")


@dataclass(frozen=True)
class SimConfig(Config):
    task: str = setting("near_target", "episode task: start near the target (20 steps) or far (100)",
                        choices=TASKS)
    sound_split: str = setting("unheard", "sound clips: heard (training) or unheard", choices=SOUND_SPLITS)
    scene_split: str = setting("test", "scenes the episodes are drawn from", choices=SCENE_SPLITS)
    world: str = setting("", "empty: the generated scenes of scene_split; map:PATH/map.yaml (a nav2 map) "
                         "or mesh:PATH (glb, gltf, obj, ply): that world, with its PATH's .world.yaml "
                         "settings when there is one")
    num_episodes: int = setting(5, "episodes to run before the node exits", min=1, max=100000)
    first_episode: int = setting(0, "index of the first episode in the episode file", min=0)
    mode: str = setting("lockstep", "lockstep: each step waits for the controller's action; "
                        "free_running: steps at rate_hz, a missing action holds the robot (counted)",
                        choices=SIM_MODES)
    rate_hz: float = setting(1.0, "steps per second in free_running mode (1 s audio frames: 1 Hz is "
                             "real time)", min=0.01, max=1000.0)
    step_timeout_s: float = setting(30.0, "lockstep: seconds to wait for a step's answer before "
                                    "aborting the run, naming the node that did not answer",
                                    min=0.1, max=3600.0)
    startup_timeout_s: float = setting(60.0, "seconds to wait for expect_nodes to subscribe",
                                       min=0.1, max=3600.0)
    start_delay_s: float = setting(0.5, "seconds from every expect_nodes subscribed to step 0, for the "
                                   "endpoints to match; DDS discovery can take about 2 s to match a viewer "
                                   "that was already running (Foxglove, rviz, a topic echo): raise it to "
                                   "watch from step 0", min=0.0, max=3600.0)
    expect_nodes: tuple[str, ...] = setting(("separator_node", "controller_node"),
                                            "nodes that must be subscribed before step 0 (of: "
                                            + ", ".join(PIPELINE_NODES) + "); with evaluator_node "
                                            "the run ends when every episode is scored")
    max_evaluator_lag: int = setting(64, "lockstep with evaluator_node: observations the sim may publish "
                                     "before the evaluator has scored them (it runs beside the control "
                                     "loop, behind it); below the step topics' history of 128, so "
                                     "nothing it has not read is dropped", min=1, max=100)
    mic_noise: float = setting(0.0, "std of white noise added to each ear, relative to the "
                               "mixture's RMS", min=0.0, max=10.0)
    sound_library: str = setting("", "sounds: empty = the built-in library, small = its test-size "
                                 "variant, or a folder <category>/<class>/<heard|unheard>/*.wav")
    scene_preset: str = setting("default", "procedural scene family", choices=("default", "small"))
    min_source_distance: float = setting(8.0, "minimum geodesic metres between sources (8 m as the "
                                         "original; small scenes need about 3)", min=0.0, max=100.0)
    acoustics: str = setting("default", "acoustics preset; fast = short RIRs without a late tail, "
                             "for tests and quick looks only", choices=("default", "fast"))
    head: str = setting("kemar", "the head the ears are simulated with: kemar, sofa:PATH (a SOFA HRIR "
                        "file with two receivers) or free_field:SPACING_M (two microphones, no head)")
    acoustics_backend: str = setting("project", "the engine of the RIR banks: project (its own) or rlr "
                                     "(RLRAudioPropagation: opt-in, CC-BY-NC 4.0, scripts/setup.sh --with-rlr)",
                                     choices=BACKENDS)
    camera: bool = setting(True, "render and publish RGB-D images")
    camera_size: int = setting(128, "width and height of the RGB and depth images", min=16, max=1024)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_file(self, "head", parse_head(self.head).path, "a SOFA HRIR file")
        if self.acoustics_backend == "rlr":
            from m2h_ros.core.world import rlr_backend

            rlr_backend.require()  # before any node starts: the opt-in install step and the licence
        if self.world:
            parse_world_spec(self.world)  # names a missing map or mesh before anything starts
        unknown = sorted(set(self.expect_nodes) - set(PIPELINE_NODES))
        if unknown:
            raise ConfigError(f"SimConfig.expect_nodes = {list(self.expect_nodes)}: unknown node(s) "
                              f"{unknown}; known: {', '.join(PIPELINE_NODES)}")


@dataclass(frozen=True)
class SeparatorNodeConfig(Config):
    checkpoint: str = setting("", "separator checkpoint (.pt); empty: the shipped compact default")
    target_class: str = setting("", "target class; empty: from each episode's EpisodeInfo (set it "
                                "for a live microphone with no simulator)", choices=TARGET_CLASSES)
    torch_threads: int = setting(0, "torch threads; 0: models.threads.inference_threads(1) = 1, "
                                 "the fastest at batch 1 on 2 cores (fused compact: 3.7 ms vs 4.2 ms "
                                 "with 2, scripts/bench/separator.py)", min=0, max=64)
    audio_output: str = setting("listener", "what separator/audio carries: listener, the listener output trained "
                                "for what a listener gets (the target's early image at the ears, "
                                "docs/design/separator.md); masked_mixture, f^B's mask on each ear of the mixture "
                                "(the target as heard); or refined, the refined estimate of the dry target with the "
                                "mixture's phase (monaural)", choices=AUDIO_OUTPUTS)
    audio_channels: str = setting("binaural", "channels of separator/audio: binaural (left, right: a person hears "
                                  "where the target is) or mono (the ear mean, for a speech recogniser); refined "
                                  "is mono either way", choices=AUDIO_CHANNELS)
    listener_checkpoint: str = setting("", "listener checkpoint (.pt) for audio_output listener; empty: the "
                                       "shipped one")
    device: str = setting("cpu", "torch device of the separator: cpu, cuda, or auto (CUDA when present). The "
                          "in-process evaluations run on the CPU: cpu gives their numbers bit for bit, a GPU "
                          "the same to float tolerance", choices=DEVICES)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_file(self, "checkpoint", self.checkpoint, "a separator checkpoint")
        check_file(self, "listener_checkpoint", self.listener_checkpoint, "a listener checkpoint")


@dataclass(frozen=True)
class ControllerConfig(Config):
    policy: str = setting("move2hear", "which controller chooses the actions (default: the paper's Move2Hear, "
                          "pi^Q near-target, pi^N + Stop far-target; docs/design/policies.md); any name "
                          "scripts/evaluate.py --list prints, other packages' plugins included", choices=CONTROLLER_NAMES)
    checkpoint: str = setting("", "checkpoint of a learned policy or of gan_et_al's sound locator; empty: "
                              "the shipped one")
    seed: int = setting(0, "seed of stochastic controllers (with each episode's own seed)", min=0)
    camera: bool = setting(True, "camera images come with each step (the simulator's, or a robot's RGB-D); "
                           "false: a controller that reads them is refused at start")

    def __post_init__(self) -> None:
        super().__post_init__()
        check_file(self, "checkpoint", self.checkpoint, "a policy or sound-locator checkpoint")


@dataclass(frozen=True)
class EvaluatorConfig(Config):
    output_dir: str = setting("", "directory for results.md/.csv/.json and the SI-SDR plot, "
                              "rewritten after the first episode, every 10 s and at the end; empty: none")
    episodes: int = setting(0, "episodes the run is to score (run_pipeline.py and the launch file set it): "
                            "tables of fewer at shutdown say the run is partial; 0: not known", min=0)
@dataclass(frozen=True)
class RecorderConfig(Config):
    output: str = setting("", "bag directory to create; empty: runs/<date-time> under the current "
                          "directory")
    overwrite: bool = setting(False, "replace a bag already at output (else the node stops, naming it)")
    topics: tuple[str, ...] = setting((), "topics to record, names or shell-style patterns (/camera/*); empty: "
                                      "every topic seen on the graph")
    exclude: tuple[str, ...] = setting((), "topics never to record, names or shell-style patterns (robot mode "
                                       "leaves out the raw camera streams: each step's images are recorded apart)")
    max_rate_hz: tuple[str, ...] = setting((), "per-topic rate limits, TOPIC=HZ (a pattern may stand for TOPIC): "
                                           "a message sooner than 1/HZ after the last one recorded on its topic "
                                           "is left out, and counted")
    compression: str = setting("none", "MCAP chunk compression: none, or zstd (as rosbag2's mcap storage presets "
                               "zstd_fast / zstd_small; Foxglove, ros2 bag and m2h-eval read it)",
                               choices=COMPRESSIONS)
    keep_derived: bool = setting(False, "true: record the spectrogram pictures, pcm-s16 tracks, path and TF "
                                 "as the run makes them (its subscriptions make the nodes build them every "
                                 "step); false: leave them out, so nobody builds them, and let m2h-derive "
                                 "(run_pipeline.py runs it after the run) add the same topics from the raw ones")
    discovery_period_s: float = setting(0.5, "how often new topics are looked for", min=0.01,
                                        max=60.0)
    live_view: bool = setting(False, "also serve the live view from this process (the node live_view_node, "
                              "with its own parameters): every recorded topic reaches it from the "
                              "recorder's subscription instead of a second delivery from each publisher")
    flush_period_s: float = setting(0.25, "the open MCAP chunk is written to disk at least this often, "
                                    "so a killed recorder loses at most about this much", min=0.01, max=60.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        TopicSelection(self.topics, self.exclude, self.max_rate_hz)  # ConfigError for a malformed rate limit


@dataclass(frozen=True)
class LiveViewConfig(Config):
    host: str = setting("127.0.0.1", "address the Foxglove WebSocket server binds to; 127.0.0.1: this "
                        "machine only (0.0.0.0 serves every network the machine is on, unauthenticated)")
    port: int = setting(8765, "TCP port of the server (8765 is Foxglove's default); 0: any free port",
                        min=0, max=65535)
    topics: tuple[str, ...] = setting((), "topics to serve; empty: every topic seen on the graph")
    discovery_period_s: float = setting(0.5, "how often new topics are looked for", min=0.01, max=60.0)


@dataclass(frozen=True)
class CaptureNodeConfig(Config):
    device: str = setting("", "audio input: empty = the default input device, a number = its PortAudio index, "
                          "else (part of) its name; capture_node --list-devices lists them")
    channels: tuple[int, ...] = setting((0, 1), "device channels to publish, 0-based, in this order (the "
                                        "separator takes two: left ear, right ear)")
    sample_rate: int = setting(0, "capture rate in Hz; 0: the device's default rate. Frames are resampled "
                               "to the separator's 16 kHz", min=0, max=768000)
    frame_s: float = setting(1.0, "seconds of audio per published frame (the separator takes 1 s)",
                             min=0.01, max=60.0)
    hop_s: float = setting(1.0, "seconds between the starts of consecutive frames (< frame_s: overlapping "
                           "frames, an estimate more often)", min=0.01, max=60.0)
    block_s: float = setting(0.02, "seconds of audio PortAudio hands over per callback", min=0.001, max=1.0)
    buffer_s: float = setting(0.25, "seconds of audio the device buffers (PortAudio's input latency): blocks "
                              "still arrive every block_s; a deeper buffer survives longer stalls of a busy "
                              "machine without an overrun", min=0.005, max=5.0)
    queue_s: float = setting(2.0, "seconds of audio kept between PortAudio's thread and the publisher; when "
                             "the node falls further behind, blocks are lost and counted", min=0.05, max=60.0)
    episode_id: str = setting("live", "episode id of the published frames (the separator restarts its memory "
                              "when it changes)")
    diagnostics_period_s: float = setting(1.0, "seconds between status reports on /diagnostics",
                                          min=0.05, max=3600.0)


@dataclass(frozen=True)
class BaseNodeConfig(MotionLimits):
    twist_stamped: bool = setting(True, "cmd_vel as geometry_msgs/TwistStamped (Jazzy's convention); false: "
                                  "plain geometry_msgs/Twist")
    frame_id: str = setting("base_link", "frame_id of the TwistStamped commands")


@dataclass(frozen=True)
class EpisodeDriverConfig(Config):
    target_class: str = setting("speech", "class of the target the robot is to hear", choices=("speech", "music"))
    task: str = setting("near_target", "what the controller is told the episode is: near_target (it moves "
                        "until the last step) or far_target (it may Stop)", choices=TASKS)
    steps: int = setting(20, "actions in the episode (observations: steps + 1)", min=1, max=100000)
    episode_id: str = setting("robot", "episode id of the published steps")
    seed: int = setting(0, "seed the controller is given (stochastic controllers)", min=0)
    camera: bool = setting(True, "pass the robot's RGB and depth images with each step")
    settle_s: float = setting(0.0, "seconds after a move ends before the next step's frame may start",
                              min=0.0, max=60.0)
    step_timeout_s: float = setting(120.0, "seconds to wait for a step's motion_result before the node "
                                    "stops, naming what did not answer", min=0.1, max=3600.0)
    input_timeout_s: float = setting(30.0, "seconds a step may wait for the robot's inputs (a microphone frame, "
                                     "odometry, camera images) before the node stops, naming what is missing",
                                     min=0.1, max=3600.0)


@dataclass(frozen=True)
class AudioCommonAdapterConfig(Config):
    audio_topic: str = setting("audio/audio_stamped", "audio_common_msgs/AudioDataStamped stream to read "
                               "(ros-drivers' audio_capture publishes it with format:=wave; its launch files "
                               "run it in the namespace audio)")
    info_topic: str = setting("audio/audio_info", "audio_common_msgs/AudioInfo of that stream: channels, rate, "
                              "sample format; frames wait for it")
    channels: tuple[int, ...] = setting((0, 1), "stream channels to publish, 0-based, in this order (the "
                                        "separator takes two: left ear, right ear)")
    frame_s: float = setting(1.0, "seconds of audio per published frame (the separator takes 1 s)",
                             min=0.01, max=60.0)
    hop_s: float = setting(1.0, "seconds between the starts of consecutive frames", min=0.01, max=60.0)
    episode_id: str = setting("live", "episode id of the published frames (the separator restarts its memory "
                              "when it changes)")
    gap_tolerance_s: float = setting(0.05, "a block stamped this much later than the previous block's end "
                                     "means samples were lost: no frame spans it", min=0.0, max=10.0)


# The pipeline's nodes and their config dataclasses, in the order the pipeline starts them: the live
# view and the recorder first (they hear every topic from its first message), the simulator last (it
# waits for the others).
NODE_CONFIGS = {"live_view_node": LiveViewConfig, "recorder_node": RecorderConfig, "evaluator_node": EvaluatorConfig,
                "controller_node": ControllerConfig, "separator_node": SeparatorNodeConfig, "sim_node": SimConfig}
# Robot mode (no simulator, no evaluator): the microphones, the base and the episode driver, which
# ends the run.
ROBOT_CONFIGS = {"recorder_node": RecorderConfig, "capture_node": CaptureNodeConfig,
                 "audio_common_adapter": AudioCommonAdapterConfig, "base_node": BaseNodeConfig,
                 "controller_node": ControllerConfig, "separator_node": SeparatorNodeConfig,
                 "episode_driver": EpisodeDriverConfig}
# Where robot mode's audio comes from (one of them runs): a microphone PortAudio sees, or a robot's
# audio_common stream.
MICROPHONES = {"capture": "capture_node", "audio_common": "audio_common_adapter"}
# Robot mode's remappings, node -> (topic, to): the microphones' frames go to the episode driver, which
# republishes the chosen ones as the steps; the controller reads the step-stamped odometry and images.
# (Here, not in topics.py: every upper-case name there is a topic name.)
ROBOT_REMAPS = {"capture_node": ((topics.AUDIO, topics.MIC_AUDIO),),
                "audio_common_adapter": ((topics.AUDIO, topics.MIC_AUDIO),),
                "controller_node": ((topics.ODOM, topics.STEP_ODOM), (topics.RGB, topics.STEP_RGB),
                                    (topics.DEPTH, topics.STEP_DEPTH))}
# What robot mode records unless told otherwise: not the raw camera streams (30 Hz from a driver, most of
# a bag), whose frames at each step the episode driver republishes on step/camera/... for the controller,
# replay and the bag's viewers; chunks compressed.
ROBOT_RECORDING = {"exclude": ("/" + topics.RGB, "/" + topics.DEPTH), "compression": "zstd"}
# A robot driver's topics that robot mode reads or writes, by the option that renames them
# (run_pipeline.py --odom-topic, robot.launch.py odom_topic:=): the pipeline's name, the robot-mode nodes that
# use it, what it is. A driver that publishes /wheel/odometry or reads /base/cmd_vel is remapped, not patched.
DRIVER_TOPICS = {
    "odom": (topics.ODOM, ("base_node", "episode_driver"), "the robot's odometry (nav_msgs/Odometry)"),
    "cmd_vel": (topics.CMD_VEL, ("base_node",), "the base's velocity command (geometry_msgs/TwistStamped, or "
                "Twist with base_node's twist_stamped: false)"),
    "rgb": (topics.RGB, ("episode_driver",), "the camera's colour image (sensor_msgs/Image)"),
    "depth": (topics.DEPTH, ("episode_driver",), "the camera's depth image (sensor_msgs/Image, 32FC1 metres or "
              "16UC1 millimetres)"),
}
# A ROS topic name as a remapping takes it: relative or absolute, tokens of letters, digits and underscores.
TOPIC_NAME = re.compile(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")


def robot_remaps(driver_topics: Mapping[str, str] | None = None) -> dict[str, tuple[tuple[str, str], ...]]:
    """Robot mode's remappings, node -> ((topic, to), ...): ROBOT_REMAPS, and each DRIVER_TOPICS entry the
    robot names otherwise (``{"odom": "/wheel/odometry"}``) in every node that uses it."""
    remaps = {node: list(pairs) for node, pairs in ROBOT_REMAPS.items()}
    for key, name in (driver_topics or {}).items():
        if key not in DRIVER_TOPICS:
            raise ConfigError(f"no driver topic {key!r} to rename; known: {', '.join(DRIVER_TOPICS)}")
        if not TOPIC_NAME.fullmatch(name):
            raise ConfigError(f"{key} topic {name!r} is not a ROS topic name (letters, digits and _ between '/', "
                              f"starting with a letter, e.g. /wheel/odometry)")
        topic, users, _ = DRIVER_TOPICS[key]
        if name != topic:
            for node in users:
                remaps.setdefault(node, []).append((topic, name))
    return {node: tuple(pairs) for node, pairs in remaps.items()}


def robot_recording(driver_topics: Mapping[str, str] | None = None) -> dict[str, object]:
    """What robot mode records by default (ROBOT_RECORDING), the raw camera streams under the driver's names."""
    names = {key: (driver_topics or {}).get(key, DRIVER_TOPICS[key][0]) for key in ("rgb", "depth")}
    return {**ROBOT_RECORDING, "exclude": tuple(n if n.startswith("/") else "/" + n for n in names.values())}
