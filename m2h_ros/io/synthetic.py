"""A synthetic recorded run: every pipeline topic of a few episodes, with arrays of realistic size and
the live evaluator's scores, written as a bag. For the replay tests and ``scripts/bench/replay.py``,
where the bag's structure matters and the sounds do not (targets are modulated noise).

Messages follow the graph's order per step k: sim (episode info at k = 0, audio, odom, agent pose,
camera, ground truth), separator (binaural, monaural, refined spectrograms, refined audio), the
controller's command (none after the last observation), the evaluator's step score, and after the last
observation the episode score. Live scores are computed step by step with the shared scoring code.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from m2h_ros import topics
from m2h_ros.core.audio.scoring import StepScores, StepTruth, score_magnitude
from m2h_ros.core.audio.stft import DEFAULT_STFT, stft
from m2h_ros.core.results import HELD, EpisodeResult, EpisodeTracker
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT
from m2h_ros.io.bag import BagWriter
from m2h_ros.io.msg_defs import typestore

STEP_NS = 50_000_000  # 20 steps per second of receive time
IMAGE_SIZE = 128


@dataclass(frozen=True)
class SyntheticRun:
    episodes: int = 2
    task: str = "near_target"
    max_steps: int = 4
    sound_split: str = "heard"
    controller: str = "random"
    seed: int = 0
    camera: bool = True
    stop_after: int | None = None  # far-target: the controller stops at this step (then one more observation)
    # The separator's outputs and the live scores are logged this many observations late, as in a
    # pipeline bag (separator and evaluator run behind the simulator), across episode boundaries.
    estimate_lag: int = 0


LATE_TOPICS = (topics.SEPARATED_BINAURAL, topics.MONAURAL, topics.REFINED, topics.SEPARATED_AUDIO,
               topics.STEP_SCORE, topics.EPISODE_SCORE)


def _types():
    return typestore().types


def _header(stamp_ns: int, frame: str):
    t = _types()
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9,
                                                                           nanosec=stamp_ns % 10**9),
                                    frame_id=frame)


def _spectrogram(kind: int, values: np.ndarray, stamp: int, episode_id: str, step: int, layout: str):
    t = _types()
    return t["m2h_msgs/msg/Spectrogram"](
        header=_header(stamp, "head"), episode_id=episode_id, step=step, kind=kind, log_magnitude=False,
        sample_rate=DEFAULT_STFT.sample_rate, n_fft=DEFAULT_STFT.n_fft, hop_length=DEFAULT_STFT.hop_length,
        layout=layout, shape=np.array(values.shape, np.uint32), data=values.astype(np.float32).ravel())


def _image(stamp: int, encoding: str, array: np.ndarray):
    t = _types()
    return t["sensor_msgs/msg/Image"](
        header=_header(stamp, "camera"), height=array.shape[0], width=array.shape[1], encoding=encoding,
        is_bigendian=0, step=array.shape[1] * array.itemsize * (array.shape[2] if array.ndim == 3 else 1),
        data=np.frombuffer(array.tobytes(), np.uint8))


def _pose_msgs(stamp: int, episode_id: str, step: int, xy: np.ndarray, heading: int,
               last_action: int) -> list[tuple[str, Any]]:
    t = _types()
    yaw = heading * np.pi / 2
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(xy[0]), y=float(xy[1]), z=1.5),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))))
    cov = np.zeros(36, np.float64)
    odom = t["nav_msgs/msg/Odometry"](
        header=_header(stamp, "map"), child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                               angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
            covariance=cov))
    agent = t["m2h_msgs/msg/AgentPose"](header=_header(stamp, "map"), episode_id=episode_id, step=step,
                                         pose=pose, node=step, heading=heading, last_action=last_action)
    return [(topics.ODOM, odom), (topics.AGENT_POSE, agent)]


def write_synthetic_run(path: str | Path, run: SyntheticRun = SyntheticRun(), *,
                        live_score: Callable[[str, int, StepScores], StepScores] | None = None,
                        writer: BagWriter | None = None) -> list[EpisodeResult]:
    """Write ``run`` as a bag at ``path`` (or into an open ``writer``); returns the live results.
    ``live_score(episode_id, step, scores)`` may alter the scores the live evaluator records."""
    t = _types()
    own = writer is None
    writer = writer or BagWriter(path)
    results = []
    clock = [1_700_000_000 * 10**9]

    late: list[tuple[int, str, Any]] = []  # (observation it belongs to, topic, message)
    observations = [0]

    def write(topic: str, message: Any) -> None:
        clock[0] += 1000
        writer.write(topic if topic.startswith("/") else "/" + topic, message.__msgtype__, clock[0], message)

    def put(topic: str, message: Any) -> None:
        if topic == topics.AUDIO:  # a new observation: what is now lag observations old comes out
            observations[0] += 1
            while late and late[0][0] <= observations[0] - run.estimate_lag:
                write(*late.pop(0)[1:])
        if run.estimate_lag and topic in LATE_TOPICS:
            late.append((observations[0], topic, message))
        else:
            write(topic, message)

    try:
        for e in range(run.episodes):
            results.append(_episode(run, e, put, clock, live_score, t))
        for _, topic, message in late:
            write(topic, message)
    finally:
        if own:
            writer.close()
    return results


def _episode(run: SyntheticRun, index: int, put, clock, live_score, t) -> EpisodeResult:
    rng = np.random.default_rng([run.seed, index])
    episode_id = f"test/{run.task}/{run.sound_split}/{index:06d}"
    n = DEFAULT_STFT.clip_samples
    stamp = clock[0]
    last = run.max_steps if run.stop_after is None else min(run.max_steps, run.stop_after + 1)
    put(topics.EPISODE, t["m2h_msgs/msg/EpisodeInfo"](
        header=_header(stamp, "map"), episode_id=episode_id, step=0, task=run.task, split=run.sound_split,
        scene_id=f"test_{index % 3:02d}", scenario="S-vs-M", target_class="speech",
        source_classes=["speech", "music"], max_steps=run.max_steps, seed=run.seed))
    # Far-target: the controller walks straight to the target, `stop_after` metres ahead, and stops there.
    far = run.stop_after is not None
    xy, heading, goal = np.zeros(2), 0, float(run.stop_after if far else 2)
    result = EpisodeResult(episode_id=episode_id, controller=run.controller, task=run.task,
                           sound_split=run.sound_split, scene_id=f"test_{index % 3:02d}",
                           target_class="speech", shortest_path=goal)
    tracker = EpisodeTracker(result, xy)
    action = HELD  # the pose of step 0 follows no action
    # One dry clip per episode, as the simulator plays it; heard from a new place (delay, gains) each step.
    envelope = 0.5 + 0.5 * np.sin(np.linspace(0, 8 * np.pi, n)) ** 2
    target = (rng.standard_normal(n) * envelope).astype(np.float32)
    for step in range(last + 1):
        clock[0] += STEP_NS
        stamp = clock[0]
        delay = int(rng.integers(20, 60))
        gains = rng.uniform(0.4, 1.0, 2)
        target_binaural = np.stack([np.roll(target, delay) * gains[0], np.roll(target, delay + 3) * gains[1]])
        target_binaural[:, :delay] = 0
        distractor = rng.standard_normal((2, n)).astype(np.float32) * 0.7
        mixture = ((target_binaural + distractor) / 2).astype(np.float32)
        geodesic = max(goal - xy[0], 0.0)
        at_target = geodesic == 0.0
        put(topics.AUDIO, t["m2h_msgs/msg/BinauralAudio"](
            header=_header(stamp, "head"), episode_id=episode_id, step=step, sample_rate=DEFAULT_STFT.sample_rate,
            channels=2, samples=mixture.ravel()))
        for topic, message in _pose_msgs(stamp, episode_id, step, xy, heading, action):
            put(topic, message)
        if run.camera:
            rgb = rng.integers(0, 255, (IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
            depth = rng.random((IMAGE_SIZE, IMAGE_SIZE), np.float32) * 10
            put(topics.RGB, _image(stamp, "rgb8", rgb))
            put(topics.DEPTH, _image(stamp, "32FC1", depth))
            put(topics.CAMERA_INFO, t["sensor_msgs/msg/CameraInfo"](
                header=_header(stamp, "camera"), height=IMAGE_SIZE, width=IMAGE_SIZE, distortion_model="plumb_bob",
                d=np.zeros(5), k=np.eye(3).ravel(), r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0,
                binning_y=0, roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                                       do_rectify=False)))
        put(topics.GROUND_TRUTH, t["m2h_msgs/msg/GroundTruth"](
            header=_header(stamp, "head"), episode_id=episode_id, step=step, sample_rate=DEFAULT_STFT.sample_rate,
            target_monaural=target, target_binaural=target_binaural.astype(np.float32).ravel(),
            target_delay=float(delay) + 1.5, geodesic_distance=geodesic, at_target=at_target,
            last_step=step == last))
        clean = np.abs(stft(target))
        refined = (clean * (1 + 0.5 * rng.random(clean.shape)) + 0.05 * rng.random(clean.shape)).astype(np.float32)
        put(topics.SEPARATED_BINAURAL, _spectrogram(1, np.abs(stft(mixture)), stamp, episode_id, step, "CFT"))
        put(topics.MONAURAL, _spectrogram(2, refined * 1.1, stamp, episode_id, step, "FT"))
        put(topics.REFINED, _spectrogram(3, refined, stamp, episode_id, step, "FT"))
        put(topics.SEPARATED_AUDIO, t["m2h_msgs/msg/BinauralAudio"](
            header=_header(stamp, "head"), episode_id=episode_id, step=step, sample_rate=DEFAULT_STFT.sample_rate,
            channels=1, samples=mixture.mean(0)))
        if step < last:
            action = STOP if step == run.stop_after else MOVE_FORWARD if far else \
                int(rng.choice([MOVE_FORWARD, MOVE_FORWARD, TURN_LEFT]))
            put(topics.COMMAND, t["m2h_msgs/msg/MotionCommand"](
                header=_header(stamp, "base_link"), episode_id=episode_id, step=step, action=action,
                controller=run.controller))
        truth = StepTruth(target_monaural=target, target_binaural=target_binaural)
        scores = score_magnitude(refined, mixture, truth)
        if live_score is not None:
            scores = live_score(episode_id, step, scores)
        tracker.observe(step, si_sdr=float(scores.si_sdr), si_sdr_mixture_phase=float(scores.si_sdr_mixture_phase),
                        stft_distance=float(scores.stft_distance), position=xy, at_target=at_target)
        put(topics.STEP_SCORE, t["m2h_msgs/msg/StepScore"](
            header=_header(stamp, "head"), episode_id=episode_id, step=step, si_sdr=float(scores.si_sdr),
            si_sdr_mixture_phase=float(scores.si_sdr_mixture_phase), stft_distance=float(scores.stft_distance),
            geodesic_distance=geodesic))
        if step < last:
            tracker.act(step, action)
            if action == MOVE_FORWARD:
                xy = xy + np.array([1.0, 0.0])
            elif action == TURN_LEFT:
                heading = (heading + 1) % 4
    result = tracker.finish()
    put(topics.EPISODE_SCORE, t["m2h_msgs/msg/EpisodeScore"](
        header=_header(clock[0], "map"), episode_id=episode_id, step=result.steps, si_sdr=result.final("si_sdr"),
        si_sdr_mixture_phase=result.final("si_sdr_mixture_phase"), stft_distance=result.final("stft_distance"),
        mean_si_sdr=float(np.mean(result.si_sdr)), success=result.success, spl=result.spl,
        path_length=result.path_length, shortest_path=result.shortest_path))
    return result
