"""sim_node: the simulator. Plays episodes on the ROS-free environment (one slot), publishes each
step's binaural mixture, camera images, odometry, episode info and (for the evaluator only) the
ground truth, and applies one MotionCommand per step.

Lockstep (default): step k is published, then the node waits for the controller's command for step
k (at most step_timeout_s; then it names the node that did not answer and exits non-zero). The
evaluator scores beside the control loop, behind it: when evaluator_node is expected, the sim
publishes at most max_evaluator_lag observations it has not scored yet (its StepScores are the
credit), so the evaluator never falls further behind than the step topics' history holds, and the
run ends when every episode is scored. Without an evaluator, an episode's last observation waits for
the separator's output, so nothing is cut off. Free-running: steps at rate_hz; a step
whose command has not arrived holds the robot in place and is counted as dropped.
The robot's path, its TF and the mixture's pcm-s16 track are built only while something subscribes.
Exits with code 0 after the last episode."""

from __future__ import annotations

import time

import numpy as np
from m2h_msgs.msg import AgentPose, BinauralAudio, EpisodeInfo, EpisodeScore, GroundTruth, MotionCommand, StepScore
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from visualization_msgs.msg import MarkerArray

from m2h_ros import sim_world, topics
from m2h_ros.core.results import HELD
from m2h_ros.core.world import frames
from m2h_ros.core.world.env import N_ACTIONS
from m2h_ros.core.world.player import EpisodePlayer, PlayerStep
from m2h_ros.errors import PipelineError
from m2h_ros.io.derived import path_markers_cdr
from m2h_ros.io.msg_defs import TF_MESSAGE
from m2h_ros.node_configs import SimConfig
from m2h_ros.ros import convert
from m2h_ros.ros.graph import missing_consumers
from m2h_ros.ros.introspection import optional_message_class, raw_audio_publisher
from m2h_ros.ros.on_demand import OnDemand, on_demand_summary
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import LATCHED, LATEST, STEP, TF, publisher_events, subscription_events, wait_for_delivery
from m2h_ros.ros.spin import RunFinished, run_node

TICK_S = 0.05  # how often the node checks start-up and timeouts (answers are handled as they come)
DELIVERY_TIMEOUT_S = 5.0  # at the end, how long to wait for every reader to acknowledge every sample


class SimNode(Node):
    def __init__(self):
        super().__init__("sim_node")
        self.config: SimConfig = declare_config(self, SimConfig)
        cfg = self.config
        library = sim_world.prepare_library(cfg)  # as scripts/run_pipeline.py does: an install has no scripts/
        env_config = sim_world.env_config(cfg)
        self.camera_config = env_config.camera_config
        self.player = EpisodePlayer(sim_world.sim_episodes(cfg, library), library, config=env_config)
        self.sample_rate = env_config.acoustics.sample_rate
        self.ear_height = env_config.acoustics.head_height
        self.indices = list(range(cfg.num_episodes))

        def publisher(kind, topic, qos=STEP):
            return self.create_publisher(kind, topic, qos, event_callbacks=publisher_events(self.get_logger(), topic))

        self.pub_episode = publisher(EpisodeInfo, topics.EPISODE, LATCHED)
        self.pub_audio = publisher(BinauralAudio, topics.AUDIO)
        self.pub_pcm = raw_audio_publisher(self, topics.AUDIO, STEP)  # where foxglove_msgs is installed
        self.pub_odom = publisher(Odometry, topics.ODOM)
        self.pub_pose = publisher(AgentPose, topics.AGENT_POSE)
        self.pub_truth = publisher(GroundTruth, topics.GROUND_TRUTH)
        self.pub_map = publisher(OccupancyGrid, topics.MAP, LATEST)
        self.pub_path = OnDemand(publisher(MarkerArray, topics.PATH))
        self.pub_sources = publisher(MarkerArray, topics.SOURCES)
        # TF where tf2_msgs is installed; elsewhere the recorder writes the same tree into the bag.
        self.tf_message = optional_message_class(TF_MESSAGE)
        self.pub_tf = None if self.tf_message is None else OnDemand(publisher(self.tf_message, topics.TF, TF))
        if self.tf_message is not None:
            self.pub_tf_static = publisher(self.tf_message, topics.TF_STATIC, LATEST)
        self.maps: dict[str, frames.OccupancyGrid] = {}  # scene fingerprint -> its grid
        self.path: list[tuple[float, float]] = []  # the robot's positions this episode
        self.last_pose: tuple[np.ndarray, int] | None = None  # pose and stamp (ns) of the last observation
        if cfg.camera:
            self.pub_rgb, self.pub_depth = publisher(Image, topics.RGB), publisher(Image, topics.DEPTH)
            self.pub_info = publisher(CameraInfo, topics.CAMERA_INFO)
        self.create_subscription(MotionCommand, topics.COMMAND, self.on_command, STEP,
                                 event_callbacks=subscription_events(self.get_logger(), topics.COMMAND))
        self.create_subscription(BinauralAudio, topics.SEPARATED_AUDIO, self.on_separated, STEP,
                                 event_callbacks=subscription_events(self.get_logger(), topics.SEPARATED_AUDIO))
        self.create_subscription(EpisodeScore, topics.EPISODE_SCORE, self.on_score, STEP,
                                 event_callbacks=subscription_events(self.get_logger(), topics.EPISODE_SCORE))
        self.scores_evaluator = "evaluator_node" in cfg.expect_nodes
        if self.scores_evaluator:
            self.create_subscription(StepScore, topics.STEP_SCORE, self.on_step_score, STEP,
                                     event_callbacks=subscription_events(self.get_logger(), topics.STEP_SCORE))
        self.commands: dict[tuple[str, int], int] = {}
        self.separated: tuple[str, int] = ("", -1)  # the last (episode, step) the separator answered
        self.scored: set[str] = set()
        self.scored_steps = 0  # StepScores received: the evaluator's progress
        self.current: PlayerStep | None = None
        self.position = -1  # index into self.indices
        self.published_at = self.first_published_at = 0.0
        self.ready_since: float | None = None
        self.started_at = time.monotonic()
        self.steps = self.dropped = 0
        self.timer = self.create_timer(TICK_S, self.tick)
        self.step_timer = None
        self.get_logger().info(f"ready: {cfg.num_episodes} {cfg.task} episodes ({cfg.sound_split} sounds, "
                               f"{cfg.world or cfg.scene_split + ' scenes'}) from #{cfg.first_episode}, {cfg.mode}")

    # --------------------------------------------------------------- callbacks
    def on_command(self, msg: MotionCommand) -> None:
        if not 0 <= msg.action < N_ACTIONS:
            raise PipelineError(f"controller {msg.controller!r} sent action {msg.action} for "
                                f"{msg.episode_id} step {msg.step}; valid actions are 0..{N_ACTIONS - 1}")
        self.commands[(msg.episode_id, msg.step)] = msg.action
        self.poll()

    def on_separated(self, msg: BinauralAudio) -> None:
        self.separated = (msg.episode_id, msg.step)
        self.poll()

    def on_score(self, msg: EpisodeScore) -> None:
        self.scored.add(msg.episode_id)
        self.poll()

    def on_step_score(self, msg: StepScore) -> None:
        self.scored_steps += 1
        self.poll()

    def poll(self) -> None:
        if self.current is not None and (self.config.mode == "lockstep" or self.current.done):
            self.lockstep(time.monotonic())

    def tick(self) -> None:
        now = time.monotonic()
        if self.current is None:
            self.wait_for_consumers(now)
        else:
            self.poll()

    # --------------------------------------------------------------- phases
    def wait_for_consumers(self, now: float) -> None:
        missing = missing_consumers(self, self.config.expect_nodes)
        if missing:
            self.ready_since = None
            if now - self.started_at > self.config.startup_timeout_s:
                raise PipelineError(f"after {self.config.startup_timeout_s:.0f} s these nodes have not "
                                    f"subscribed: {'; '.join(missing)}")
            return
        if self.ready_since is None:
            self.ready_since = now
        elif now - self.ready_since >= self.config.start_delay_s:
            self.get_logger().info(f"consumers ready ({', '.join(self.config.expect_nodes)}): starting")
            self.next_episode()
            if self.config.mode == "free_running":
                self.step_timer = self.create_timer(1.0 / self.config.rate_hz, self.free_step)

    def lockstep(self, now: float) -> None:
        episode_id, step = self.player.episode.episode_id, int(self.current.obs["step"][0])
        if self.current.done:
            if self.scores_evaluator:
                last = self.position == len(self.indices) - 1
                answered = len(self.scored) == len(self.indices) if last else self.evaluator_keeps_up()
            else:
                answered = self.separated == (episode_id, step)
            if answered:
                self.next_episode()
            elif now - self.published_at > self.config.step_timeout_s:
                who = self.unscored() if self.scores_evaluator else "separator_node sent no output"
                raise PipelineError(f"episode {episode_id} ended at step {step} and {who} for "
                                    f"{self.config.step_timeout_s} s{self.absent_nodes()}")
            return
        action = self.commands.get((episode_id, step))
        if action is not None and self.evaluator_keeps_up():
            del self.commands[(episode_id, step)]
            self.advance(action)
        elif now - self.published_at > self.config.step_timeout_s:
            if action is not None:
                raise PipelineError(f"{episode_id} step {step}: {self.unscored()} for {self.config.step_timeout_s} s"
                                    f"{self.absent_nodes()}")
            # What the sim saw, not a verdict: a stalled transport looks the same as a silent node.
            culprit = ("controller_node did not answer (the separator's output for this step reached the sim)"
                       if self.separated == (episode_id, step) else
                       "separator_node did not answer, or its output for this step was not delivered")
            raise PipelineError(f"no motion command for {episode_id} step {step} within "
                                f"{self.config.step_timeout_s} s: {culprit}{self.absent_nodes()}")

    def unscored(self) -> str:
        return f"evaluator_node left {self.steps - self.scored_steps} observations unscored"

    def evaluator_keeps_up(self) -> bool:
        """Whether one more observation stays within max_evaluator_lag of the evaluator's scores."""
        return not self.scores_evaluator or self.steps - self.scored_steps < self.config.max_evaluator_lag

    def free_step(self) -> None:
        if self.current is None or self.current.done:
            return
        key = (self.player.episode.episode_id, int(self.current.obs["step"][0]))
        action = self.commands.pop(key, None)
        if action is None:
            self.dropped += 1
        self.advance(action)

    def absent_nodes(self) -> str:
        present = set(self.get_node_names())
        gone = [name for name in self.config.expect_nodes if name not in present]
        return f" ({', '.join(gone)} no longer in the graph)" if gone else ""

    # --------------------------------------------------------------- stepping
    def next_episode(self) -> None:
        self.position += 1
        if self.position == len(self.indices):
            elapsed = time.monotonic() - self.first_published_at
            dropped = f", {self.dropped} dropped (held)" if self.config.mode == "free_running" else ""
            self.get_logger().info(f"done: {len(self.indices)} episodes, {self.steps} steps in {elapsed:.1f} s "
                                   f"({self.steps / max(elapsed, 1e-9):.1f} steps/s){dropped}")
            wait_for_delivery(self, timeout_s=DELIVERY_TIMEOUT_S)
            raise RunFinished()
        self.current = self.player.start(self.indices[self.position])
        self.commands = {k: v for k, v in self.commands.items() if k[0] == self.player.episode.episode_id}
        self.publish(episode_start=True)

    def advance(self, action: int | None) -> None:
        """Apply ``action``; None holds the robot where it is (free-running, no command in time)."""
        self.current = self.player.step(0 if action is None else action, hold=action is None)
        self.publish(episode_start=False, last_action=HELD if action is None else action)

    def publish(self, *, episode_start: bool, last_action: int = HELD) -> None:
        obs, info, episode = self.current.obs, self.current.info, self.player.episode
        stamp = self.get_clock().now().nanoseconds
        step = int(obs["step"][0])
        tag = dict(episode_id=episode.episode_id, step=step, stamp_ns=stamp)
        if episode_start:
            self.pub_episode.publish(convert.episode_info_msg(episode, stamp_ns=stamp))
            self.publish_scene(stamp)
        # The mixture first: the separator (the longest stage) starts while the rest goes out.
        self.pub_audio.publish(convert.audio_msg(obs["audio"][0], sample_rate=self.sample_rate, **tag))
        if self.pub_pcm is not None:
            self.pub_pcm.send(obs["audio"][0], self.sample_rate, stamp)
        pose = obs["pose"][0]
        previous = None if episode_start else self.last_pose
        twist = frames.twist(previous[0], pose, (stamp - previous[1]) / 1e9) if previous else (0.0, 0.0, 0.0)
        self.last_pose = (pose, stamp)
        self.pub_odom.publish(convert.odometry_msg(pose, twist=twist, stamp_ns=stamp))
        if self.pub_tf is not None:
            self.pub_tf.publish(lambda: self.tf_message(transforms=convert.transform_msgs(
                [frames.base_transform(pose)], stamp_ns=stamp)))
        self.pub_pose.publish(convert.agent_pose_msg(pose, node=int(obs["node"][0]), heading=int(obs["heading"][0]),
                                                     last_action=last_action, height=self.ear_height, **tag))
        if self.config.camera:
            self.pub_rgb.publish(convert.rgb_msg(obs["rgb"][0], stamp_ns=stamp))
            self.pub_depth.publish(convert.depth_msg(obs["depth"][0, ..., 0], stamp_ns=stamp))
            self.pub_info.publish(convert.camera_info_msg(self.camera_config, stamp_ns=stamp))
        self.pub_truth.publish(convert.ground_truth_msg(info, 0, sample_rate=self.sample_rate,
                                                         last_step=self.current.done, **tag))
        self.path.append((float(pose[0]), float(pose[1])))
        self.pub_path.publish(lambda: path_markers_cdr(np.array(self.path), height=self.ear_height, stamp_ns=stamp))
        self.published_at = time.monotonic()
        if not self.steps:
            self.first_published_at = self.published_at
        self.steps += 1

    def publish_scene(self, stamp: int) -> None:
        """At an episode's start: its floor plan, where its sources are (ground truth) and, once, the
        static frames."""
        scene, episode = self.player.scene, self.player.episode
        grid = self.maps.get(scene.fingerprint())
        if grid is None:
            grid = self.maps[scene.fingerprint()] = frames.occupancy_grid(scene)
        self.pub_map.publish(convert.occupancy_grid_msg(grid, stamp_ns=stamp))
        self.pub_sources.publish(convert.source_markers(
            scene.grid.positions[list(episode.source_nodes)], episode.source_categories,
            height=self.ear_height, stamp_ns=stamp))
        self.path = []
        if self.tf_message is not None and self.position == 0:
            static = frames.static_transforms(head_height=self.ear_height, eye_height=self.camera_config.eye_height)
            self.pub_tf_static.publish(self.tf_message(transforms=convert.transform_msgs(static, stamp_ns=stamp)))

    def destroy_node(self) -> None:
        print(f"sim_node: {on_demand_summary([self.pub_path, self.pub_pcm, self.pub_tf])}",
              flush=True)
        self.player.close()
        super().destroy_node()


def main(args=None):
    run_node(SimNode, args)


if __name__ == "__main__":
    main()
