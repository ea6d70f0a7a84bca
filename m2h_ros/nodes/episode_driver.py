"""episode_driver: turns a robot's continuous microphone stream into the pipeline's steps (robot mode).

The microphones (capture_node, or the audio_common adapter) publish frames on `mic/audio` all the
time. Step 0 is the first frame; after that, step k+1 is the first frame captured wholly after the
base reported the move of step k (`motion_result`), so no step's audio mixes a move with standing
still. Each step goes out as the simulator's would: the frame on `audio` with this episode's id and the
step number, and, stamped like it, the robot's latest odometry on `step/odom` and (camera: true) its
latest RGB and depth images on `step/camera/...`, which the controller binds to the step by stamp.
`episode` (latched) carries the target class and the episode length. The last step is step `steps`, or
the one after the far-target controller's Stop was carried out; the node exits 0 once the separator has
published its audio for that step (`separator/audio`, the estimate a listener gets), so a run stopped
then has every step's estimate."""

from __future__ import annotations

import time

from m2h_msgs.msg import BinauralAudio, EpisodeInfo, MotionCommand, MotionResult
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from m2h_ros import topics
from m2h_ros.errors import PipelineError
from m2h_ros.node_configs import EpisodeDriverConfig
from m2h_ros.ros import convert
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import LATCHED, STEP, publisher_events, subscription_events, wait_for_delivery
from m2h_ros.ros.spin import RunFinished, run_node

TICK_S = 0.1
FINAL_DELIVERY_S = 2.0  # how long the last step's messages may wait for their readers' acks


class EpisodeDriver(Node):
    def __init__(self):
        super().__init__("episode_driver")
        self.config: EpisodeDriverConfig = declare_config(self, EpisodeDriverConfig)
        cfg = self.config

        def publisher(kind, topic, qos=STEP):
            return self.create_publisher(kind, topic, qos, event_callbacks=publisher_events(self.get_logger(), topic))

        def subscribe(kind, topic, callback, qos=STEP):
            self.create_subscription(kind, topic, callback, qos,
                                     event_callbacks=subscription_events(self.get_logger(), topic))

        self.pub_episode = publisher(EpisodeInfo, topics.EPISODE, LATCHED)
        self.pub_audio = publisher(BinauralAudio, topics.AUDIO)
        self.pub_odom = publisher(Odometry, topics.STEP_ODOM)
        subscribe(BinauralAudio, topics.MIC_AUDIO, self.on_frame)
        subscribe(MotionResult, topics.MOTION_RESULT, self.on_result)
        subscribe(MotionCommand, topics.COMMAND, self.on_command)
        subscribe(Odometry, topics.ODOM, self.on_odom, qos_profile_sensor_data)
        subscribe(BinauralAudio, topics.SEPARATED_AUDIO, self.on_separated)
        self.images: dict[str, Image] = {}
        self.pub_images = {}
        if cfg.camera:
            for topic, out in ((topics.RGB, topics.STEP_RGB), (topics.DEPTH, topics.STEP_DEPTH)):
                self.pub_images[topic] = publisher(Image, out)
                subscribe(Image, topic, lambda m, topic=topic: self.images.__setitem__(topic, m), qos_profile_sensor_data)
        self.odom: Odometry | None = None
        self.heard_frame = False  # a microphone frame came since the step began waiting for its inputs
        self.inputs_since = time.monotonic()  # when the current step began waiting for its inputs
        self.step = 0
        self.ready_after_ns = 0  # the next step's frame must start at or after this capture time
        self.waiting_since: float | None = None  # monotonic time the last step went out
        self.stopped = False  # the controller sent Stop (far-target): its move ends the episode
        self.last_step: int | None = None  # set once the episode's last step is out
        self.create_timer(TICK_S, self.tick)
        info = EpisodeInfo(episode_id=cfg.episode_id, task=cfg.task, split="robot", scene_id="robot",
                           scenario="any", target_class=cfg.target_class, source_classes=[cfg.target_class],
                           max_steps=cfg.steps, seed=cfg.seed)
        info.header.stamp = self.get_clock().now().to_msg()
        self.pub_episode.publish(info)
        self.get_logger().info(f"ready: episode {cfg.episode_id!r}, {cfg.steps} steps toward the {cfg.target_class} "
                               f"target ({cfg.task}){', with camera images' if cfg.camera else ''}")

    def on_odom(self, msg: Odometry) -> None:
        self.odom = msg

    def on_command(self, msg: MotionCommand) -> None:
        if msg.episode_id == self.config.episode_id and msg.action == MotionCommand.STOP \
                and self.config.task == "far_target":
            self.stopped = True

    def on_frame(self, msg: BinauralAudio) -> None:
        if self.waiting_since is not None:
            return  # the step before is still being carried out
        self.heard_frame = True
        start_ns = convert.nanoseconds_of(msg.header.stamp)  # capture time of the frame's first sample
        if start_ns < self.ready_after_ns:
            return
        if self.odom is None:
            self.get_logger().warning(f"no odometry on {self.resolve_topic_name(topics.ODOM)} yet: step {self.step} waits for it",
                                      throttle_duration_sec=5.0)
            return
        if any(topic not in self.images for topic in self.pub_images):
            self.get_logger().warning(f"no camera images yet on {', '.join(self.pub_images)}: step {self.step} "
                                      "waits for them", throttle_duration_sec=5.0)
            return
        msg.episode_id, msg.step = self.config.episode_id, self.step
        self.pub_audio.publish(msg)
        odom = self.odom
        odom.header.stamp = msg.header.stamp
        self.pub_odom.publish(odom)
        for topic, publisher in self.pub_images.items():
            image = self.images[topic]
            image.header.stamp = msg.header.stamp
            publisher.publish(image)
        self.get_logger().info(f"step {self.step} out")
        if self.step >= self.config.steps or (self.stopped and self.step > 0):
            self.last_step = self.step
        self.waiting_since = time.monotonic()

    def on_separated(self, msg: BinauralAudio) -> None:
        if self.last_step is not None and (msg.episode_id, msg.step) == (self.config.episode_id, self.last_step):
            # The separator can answer within milliseconds, before the recorder has the step's odometry
            # and images (missing from 2 of 5 bags without this wait).
            wait_for_delivery(self, timeout_s=FINAL_DELIVERY_S)
            self.get_logger().info(f"done: {self.last_step + 1} observations, each separated")
            raise RunFinished()

    def on_result(self, msg: MotionResult) -> None:
        if msg.episode_id != self.config.episode_id or msg.step != self.step or self.waiting_since is None:
            return
        # The next frame must begin after the move ended (+ settle_s: the base comes to rest).
        self.ready_after_ns = convert.nanoseconds_of(msg.header.stamp) + int(self.config.settle_s * 1e9)
        self.step += 1
        self.waiting_since = None
        self.heard_frame, self.inputs_since = False, time.monotonic()

    def missing_inputs(self) -> list[str]:
        """What the current step still waits for."""
        missing = [] if self.heard_frame else [f"microphone frames on {self.resolve_topic_name(topics.MIC_AUDIO)}"]
        if self.odom is None:
            missing.append(f"odometry on {self.resolve_topic_name(topics.ODOM)}")
        images = [self.resolve_topic_name(topic) for topic in self.pub_images if topic not in self.images]
        if images:
            missing.append(f"camera images on {', '.join(images)}")
        return missing

    def tick(self) -> None:
        now = time.monotonic()
        if self.waiting_since is None:
            if now - self.inputs_since > self.config.input_timeout_s and (missing := self.missing_inputs()):
                raise PipelineError(f"step {self.step}: no {'; no '.join(missing)} within "
                                    f"{self.config.input_timeout_s:g} s (input_timeout_s). Are the robot's drivers "
                                    "running, on these topics (ros2 topic list)?")
            return
        if now - self.waiting_since <= self.config.step_timeout_s:
            return
        if self.last_step is not None:
            raise PipelineError(f"no {topics.SEPARATED_AUDIO} for the last step {self.last_step} within "
                                f"{self.config.step_timeout_s:g} s: the separator did not answer it")
        raise PipelineError(f"no motion_result for step {self.step} within {self.config.step_timeout_s:g} s: "
                            "the controller sent no command or the base did not report the move")


def main(args=None):
    run_node(EpisodeDriver, args)


if __name__ == "__main__":
    main()
