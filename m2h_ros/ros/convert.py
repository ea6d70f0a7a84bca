"""Conversions between the core's arrays / dataclasses and ROS messages (both directions).

Array fields are filled from bytes (``array.array(code, arr.tobytes())``), never element by element,
and read back with ``np.frombuffer``. Every ``*_from_msg`` checks what it reads (sizes, finiteness)
and raises AudioError / PipelineError naming the message and what is wrong.
"""

from __future__ import annotations

import array
import math

import numpy as np
from builtin_interfaces.msg import Time
from m2h_msgs.msg import (AgentPose, BinauralAudio, EpisodeInfo, EpisodeScore, GroundTruth,
                          MotionCommand, Spectrogram, StepScore)
from geometry_msgs.msg import Pose, TransformStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from m2h_ros.agents.base import EpisodeStart
from m2h_ros.core.audio.pcm import pcm_int16
from m2h_ros.core.audio.scoring import StepTruth
from m2h_ros.core.audio.stft import StftConfig
from m2h_ros.core.world.camera import CameraConfig
from m2h_ros.core.world.episodes import Episode
from m2h_ros.core.world.frames import BASE, CAMERA, HEAD, MAP, ODOM, quaternion_yaw, yaw_rotation
from m2h_ros.core.world.frames import OccupancyGrid as Grid
from m2h_ros.errors import AudioError, PipelineError
from m2h_ros.io.derived import PCM_GAIN

MAP_FRAME, ODOM_FRAME, BASE_FRAME, HEAD_FRAME, CAMERA_FRAME = MAP, ODOM, BASE, HEAD, CAMERA


def stamp_of(nanoseconds: int) -> Time:
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def nanoseconds_of(stamp: Time) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _floats(values: np.ndarray) -> array.array:
    return array.array("f", np.ascontiguousarray(values, np.float32).tobytes())


def _read_floats(data, expected: int, what: str) -> np.ndarray:
    values = np.frombuffer(data, np.float32) if isinstance(data, array.array) else np.asarray(data, np.float32)
    if values.size != expected:
        raise AudioError(f"{what}: {values.size} values, expected {expected}")
    if not np.all(np.isfinite(values)):
        raise AudioError(f"{what}: holds NaN or infinite values")
    return values


def _tag(msg, episode_id: str, step: int, stamp_ns: int, frame: str):
    msg.header.stamp = stamp_of(stamp_ns)
    msg.header.frame_id = frame
    msg.episode_id, msg.step = episode_id, int(step)
    return msg


# --- audio and spectrograms ---------------------------------------------------------------------

def audio_msg(samples: np.ndarray, *, sample_rate: int, episode_id: str, step: int, stamp_ns: int) -> BinauralAudio:
    """(C, N) float32 planar samples -> BinauralAudio."""
    samples = np.asarray(samples, np.float32)
    msg = _tag(BinauralAudio(), episode_id, step, stamp_ns, HEAD_FRAME)
    msg.sample_rate, msg.channels = int(sample_rate), int(samples.shape[0])
    msg.samples = _floats(samples)
    return msg


def audio_from_msg(msg: BinauralAudio, *, sample_rate: int, samples: int, channels: int = 2) -> np.ndarray:
    """BinauralAudio -> (channels, samples) float32; AudioError if it is not what the pipeline expects."""
    what = f"audio of {msg.episode_id or '<no episode>'} step {msg.step}"
    if msg.sample_rate != sample_rate:
        raise AudioError(f"{what}: sample rate {msg.sample_rate} Hz, expected {sample_rate} Hz")
    if msg.channels != channels:
        raise AudioError(f"{what}: {msg.channels} channels, expected {channels}")
    return _read_floats(msg.samples, channels * samples, what).reshape(channels, samples)


def spectrogram_msg(values: np.ndarray, *, kind: int, layout: str, stft: StftConfig, episode_id: str,
                    step: int, stamp_ns: int) -> Spectrogram:
    """A linear magnitude (shape named by ``layout``, e.g. "CFT" or "FT") -> Spectrogram."""
    values = np.asarray(values, np.float32)
    if len(layout) != values.ndim:
        raise AudioError(f"layout {layout!r} does not name the {values.ndim} dimensions of {values.shape}")
    msg = _tag(Spectrogram(), episode_id, step, stamp_ns, HEAD_FRAME)
    msg.kind, msg.log_magnitude = int(kind), False
    msg.sample_rate, msg.n_fft, msg.hop_length = stft.sample_rate, stft.n_fft, stft.hop_length
    msg.layout, msg.shape = layout, [int(n) for n in values.shape]
    msg.data = _floats(values)
    return msg


def spectrogram_from_msg(msg: Spectrogram, *, kind: int, shape: tuple[int, ...]) -> np.ndarray:
    what = f"spectrogram (kind {msg.kind}) of {msg.episode_id} step {msg.step}"
    if msg.kind != kind:
        raise PipelineError(f"{what}: expected kind {kind}")
    if tuple(msg.shape) != tuple(shape):
        raise AudioError(f"{what}: shape {list(msg.shape)}, expected {list(shape)}")
    if msg.log_magnitude:
        raise AudioError(f"{what}: log magnitudes; the pipeline passes linear magnitudes")
    return _read_floats(msg.data, int(np.prod(shape)), what).reshape(shape)


# --- camera, pose ---------------------------------------------------------------------------------

def rgb_msg(rgb: np.ndarray, *, stamp_ns: int) -> Image:
    height, width, _ = rgb.shape
    msg = Image(height=height, width=width, encoding="rgb8", is_bigendian=0, step=3 * width)
    msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), CAMERA_FRAME
    msg.data = array.array("B", np.ascontiguousarray(rgb, np.uint8).tobytes())
    return msg


def depth_msg(depth: np.ndarray, *, stamp_ns: int) -> Image:
    height, width = depth.shape
    msg = Image(height=height, width=width, encoding="32FC1", is_bigendian=0, step=4 * width)
    msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), CAMERA_FRAME
    msg.data = array.array("B", np.ascontiguousarray(depth, "<f4").tobytes())
    return msg


def image_from_msg(msg: Image) -> np.ndarray:
    """rgb8 / bgr8 -> (H, W, 3) uint8 in RGB order; 32FC1 (metres) / 16UC1 (millimetres, as RealSense and
    OpenNI drivers publish depth) -> (H, W) float32 metres. Rows may be padded (``step``)."""
    kinds = {"rgb8": ("u1", 3), "bgr8": ("u1", 3), "32FC1": ("f4", 1), "16UC1": ("u2", 1)}
    if msg.encoding not in kinds:
        raise PipelineError(f"image encoding {msg.encoding!r} is not one of {sorted(kinds)}")
    code, channels = kinds[msg.encoding]
    dtype = np.dtype(code).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * channels * dtype.itemsize
    if msg.step < row_bytes or len(msg.data) != msg.step * msg.height:
        raise PipelineError(f"{msg.encoding} image of {msg.height}x{msg.width} (step {msg.step}) holds "
                            f"{len(msg.data)} bytes")
    rows = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)[:, :row_bytes]
    values = np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width, channels)
    if msg.encoding == "bgr8":
        return values[..., ::-1]
    if channels == 3:
        return values
    return values[..., 0].astype(np.float32) / (1000.0 if msg.encoding == "16UC1" else 1.0)


def camera_info_msg(config: CameraConfig, *, stamp_ns: int) -> CameraInfo:
    """Pinhole intrinsics of the simulated camera (no distortion)."""
    f, cx, cy = config.focal, config.width / 2, config.height / 2
    msg = CameraInfo(height=config.height, width=config.width, distortion_model="plumb_bob")
    msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), CAMERA_FRAME
    msg.d = [0.0] * 5
    msg.k = [f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def _pose(pose: np.ndarray, height: float) -> Pose:
    x, y, yaw = (float(v) for v in pose)
    msg = Pose()
    msg.position.x, msg.position.y, msg.position.z = x, y, float(height)
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = yaw_rotation(yaw)
    return msg


def odometry_msg(pose: np.ndarray, *, twist=(0.0, 0.0, 0.0), stamp_ns: int) -> Odometry:
    """(x, y, yaw) of base_link on the floor, and its twist (forward, leftward m/s, turn rad/s, in
    base_link) -> Odometry in the odom frame (REP 105)."""
    msg = Odometry(child_frame_id=BASE_FRAME)
    msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), ODOM_FRAME
    msg.pose.pose = _pose(pose, 0.0)
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.angular.z = (float(v) for v in twist)
    return msg


def pose_from_odometry(msg: Odometry) -> np.ndarray:
    """Odometry -> (x, y, yaw) float32, yaw from the quaternion about +z."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return np.array([p.x, p.y, quaternion_yaw(q.x, q.y, q.z, q.w) % (2 * math.pi)], np.float32)


def agent_pose_msg(pose: np.ndarray, *, node: int, heading: int, last_action: int, height: float,
                   episode_id: str, step: int, stamp_ns: int) -> AgentPose:
    msg = _tag(AgentPose(), episode_id, step, stamp_ns, MAP_FRAME)
    msg.pose = _pose(pose, height)
    msg.node, msg.heading, msg.last_action = int(node), int(heading), int(last_action)
    return msg


def position_of(msg: AgentPose) -> np.ndarray:
    return np.array([msg.pose.position.x, msg.pose.position.y], np.float64)


# --- what rviz and Foxglove show: TF, the map, markers, spectrogram pictures --------------------

def transform_msgs(transforms, *, stamp_ns: int) -> list[TransformStamped]:
    """core.world.frames Transforms -> TransformStamped (for a tf2_msgs/TFMessage)."""
    out = []
    for tr in transforms:
        msg = TransformStamped(child_frame_id=tr.child)
        msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), tr.parent
        t, r = msg.transform.translation, msg.transform.rotation
        t.x, t.y, t.z = (float(v) for v in tr.translation)
        r.x, r.y, r.z, r.w = (float(v) for v in tr.rotation)
        out.append(msg)
    return out


def occupancy_grid_msg(grid: Grid, *, stamp_ns: int) -> OccupancyGrid:
    rows, cols = grid.cells.shape
    msg = OccupancyGrid()
    msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), MAP_FRAME
    msg.info.map_load_time = msg.header.stamp
    msg.info.resolution, msg.info.width, msg.info.height = float(grid.resolution), cols, rows
    msg.info.origin.position.x, msg.info.origin.position.y = (float(v) for v in grid.origin)
    msg.info.origin.orientation.z = math.sin(float(grid.yaw) / 2)
    msg.info.origin.orientation.w = math.cos(float(grid.yaw) / 2)
    msg.data = array.array("b", np.ascontiguousarray(grid.cells, np.int8).tobytes())
    return msg


def _marker(kind: int, *, namespace: str, marker_id: int, stamp_ns: int, rgba, scale) -> Marker:
    msg = Marker(type=kind, action=Marker.ADD, ns=namespace, id=marker_id)
    msg.header.stamp, msg.header.frame_id = stamp_of(stamp_ns), MAP_FRAME
    msg.pose.orientation.w = 1.0
    msg.scale.x, msg.scale.y, msg.scale.z = (float(v) for v in scale)
    msg.color = ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))
    return msg


TARGET_COLOUR, DISTRACTOR_COLOUR = (0.1, 0.7, 0.2, 0.9), (0.85, 0.2, 0.15, 0.9)


def source_markers(positions: np.ndarray, categories, *, height: float, stamp_ns: int) -> MarkerArray:
    """Where the sources are, target first, (K, 2) metres: a sphere each (target green, distractors red)
    and its category above it; the first marker deletes the previous episode's."""
    clear = Marker(action=Marker.DELETEALL)
    clear.header.stamp, clear.header.frame_id = stamp_of(stamp_ns), MAP_FRAME
    markers = [clear]
    for k, ((x, y), category) in enumerate(zip(np.asarray(positions, float).reshape(-1, 2), categories, strict=True)):
        rgba = TARGET_COLOUR if k == 0 else DISTRACTOR_COLOUR
        ball = _marker(Marker.SPHERE, namespace="sources", marker_id=k, stamp_ns=stamp_ns, rgba=rgba,
                       scale=(0.4, 0.4, 0.4))
        label = _marker(Marker.TEXT_VIEW_FACING, namespace="source_labels", marker_id=k, stamp_ns=stamp_ns,
                        rgba=(1.0, 1.0, 1.0, 1.0), scale=(0.0, 0.0, 0.3))
        ball.pose.position.x, ball.pose.position.y, ball.pose.position.z = float(x), float(y), float(height)
        label.pose.position.x, label.pose.position.y, label.pose.position.z = float(x), float(y), float(height) + 0.5
        label.text = f"{'target' if k == 0 else 'distractor'}: {category}"
        markers += [ball, label]
    return MarkerArray(markers=markers)


def raw_audio_msg(raw_audio: type, samples: np.ndarray, *, sample_rate: int, stamp_ns: int):
    """(channels, N) float samples -> foxglove_msgs/RawAudio (``raw_audio``, where installed), pcm-s16 at
    the bags' gain (what the recorder writes where the package is missing)."""
    samples = np.atleast_2d(np.asarray(samples, np.float32))
    msg = raw_audio(format="pcm-s16", sample_rate=int(sample_rate), number_of_channels=samples.shape[0])
    msg.timestamp = stamp_of(stamp_ns)
    msg.data = array.array("B", pcm_int16(samples, gain=PCM_GAIN))
    return msg


# --- episodes, ground truth, commands, scores ---------------------------------------------------

def episode_info_msg(episode: Episode, *, stamp_ns: int) -> EpisodeInfo:
    msg = _tag(EpisodeInfo(), episode.episode_id, 0, stamp_ns, MAP_FRAME)
    msg.task, msg.split, msg.scene_id, msg.scenario = episode.task, episode.sound_split, episode.scene_id, episode.scenario
    msg.target_class, msg.source_classes = episode.target_category, list(episode.source_categories)
    msg.max_steps, msg.seed = episode.max_steps, episode.seed
    return msg


def episode_start_from_msg(msg: EpisodeInfo) -> EpisodeStart:
    return EpisodeStart(msg.episode_id, msg.task, msg.target_class, int(msg.max_steps), int(msg.seed))


def ground_truth_msg(info: dict, slot: int, *, sample_rate: int, last_step: bool, episode_id: str, step: int,
                     stamp_ns: int) -> GroundTruth:
    """One slot of the environment's ``info`` -> GroundTruth (what only the evaluator gets)."""
    msg = _tag(GroundTruth(), episode_id, step, stamp_ns, HEAD_FRAME)
    msg.sample_rate = int(sample_rate)
    msg.target_monaural = _floats(info["target_monaural"][slot])
    msg.target_binaural = _floats(info["target_binaural"][slot])
    msg.target_delay = float(info["target_delay"][slot])
    msg.geodesic_distance = float(info["geodesic_distance"][slot])
    msg.at_target = bool(info["at_target"][slot])
    msg.last_step = bool(last_step)
    return msg


def truth_from_msg(msg: GroundTruth, *, samples: int) -> StepTruth:
    what = f"ground truth of {msg.episode_id} step {msg.step}"
    return StepTruth(target_monaural=_read_floats(msg.target_monaural, samples, what)[None],
                     target_binaural=_read_floats(msg.target_binaural, 2 * samples, what).reshape(1, 2, samples))


def command_msg(action: int, *, controller: str, episode_id: str, step: int, stamp_ns: int) -> MotionCommand:
    msg = _tag(MotionCommand(), episode_id, step, stamp_ns, BASE_FRAME)
    msg.action, msg.controller = int(action), controller
    return msg


def step_score_msg(*, si_sdr: float, si_sdr_mixture_phase: float, stft_distance: float,
                   geodesic_distance: float, episode_id: str, step: int, stamp_ns: int) -> StepScore:
    msg = _tag(StepScore(), episode_id, step, stamp_ns, MAP_FRAME)
    msg.si_sdr, msg.si_sdr_mixture_phase = float(si_sdr), float(si_sdr_mixture_phase)
    msg.stft_distance, msg.geodesic_distance = float(stft_distance), float(geodesic_distance)
    return msg


def episode_score_msg(result, *, stamp_ns: int) -> EpisodeScore:
    """A finished core.results.EpisodeResult -> EpisodeScore."""
    msg = _tag(EpisodeScore(), result.episode_id, result.steps, stamp_ns, MAP_FRAME)
    msg.si_sdr, msg.si_sdr_mixture_phase = result.final("si_sdr"), result.final("si_sdr_mixture_phase")
    msg.stft_distance = result.final("stft_distance")
    msg.mean_si_sdr = float(np.mean(result.si_sdr))
    msg.success, msg.spl = bool(result.success), float(result.spl)
    msg.path_length, msg.shortest_path = float(result.path_length), float(result.shortest_path)
    return msg
