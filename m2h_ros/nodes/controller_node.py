"""controller_node: chooses each step's MotionCommand with any controller of m2h_ros.agents.

For step k it gathers the mixture and the odometry of that step, the separator's three outputs and
the camera images when the controller uses them, builds the same ControllerObservation the
in-process evaluation builds, and publishes one command. A controller that does not read the
separator (every training-free baseline) answers without waiting for it. It never subscribes to the ground truth.
No command answers an episode's last observation (step max_steps, or the one after a far-target Stop)."""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # learned controllers load torch

import numpy as np  # noqa: E402
from m2h_msgs.msg import BinauralAudio, EpisodeInfo, MotionCommand, Spectrogram  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from m2h_ros import topics  # noqa: E402
from m2h_ros.agents.base import ControllerObservation, SingleEpisode  # noqa: E402
from m2h_ros.agents.registry import TRAINING_FREE, make_controller  # noqa: E402
from m2h_ros.core.audio.stft import DEFAULT_STFT  # noqa: E402
from m2h_ros.core.robot.images import fit_depth, fit_rgb  # noqa: E402
from m2h_ros.core.world.episodes import STOP  # noqa: E402
from m2h_ros.errors import ConfigError  # noqa: E402
from m2h_ros.node_configs import ControllerConfig  # noqa: E402
from m2h_ros.ros import convert  # noqa: E402
from m2h_ros.ros.params import declare_config  # noqa: E402
from m2h_ros.ros.qos import LATCHED, STEP, publisher_events, subscription_events  # noqa: E402
from m2h_ros.ros.spin import run_node  # noqa: E402
from m2h_ros.ros.sync import EpisodeGate, StepAssembler  # noqa: E402

F, T = DEFAULT_STFT.n_freq, DEFAULT_STFT.n_frames


class ControllerNode(Node):
    def __init__(self):
        super().__init__("controller_node")
        self.config: ControllerConfig = declare_config(self, ControllerConfig)
        cfg = self.config
        self.controller = SingleEpisode(make_controller(cfg.policy, 1, seed=cfg.seed, checkpoint=cfg.checkpoint))
        camera, separator = self.controller.controller.uses_camera, self.controller.controller.uses_separator
        if camera and not cfg.camera:
            raise ConfigError(f"controller {cfg.policy!r} reads camera images and camera is false: without a camera "
                              f"only controllers that read none run (the training-free baselines: "
                              f"{', '.join(TRAINING_FREE)})")
        parts = ({"audio", "odom"} | ({"binaural", "monaural", "refined"} if separator else set())
                 | ({"rgb", "depth"} if camera else set()))
        self.gate = EpisodeGate(self.on_step)  # steps wait for their episode's info
        self.assembler = StepAssembler(parts, self.gate.step)
        self.pub_command = self.create_publisher(MotionCommand, topics.COMMAND, STEP,
                                                 event_callbacks=publisher_events(self.get_logger(), topics.COMMAND))

        def subscribe(kind, topic, callback, qos=STEP):
            self.create_subscription(kind, topic, callback, qos,
                                     event_callbacks=subscription_events(self.get_logger(), topic))

        subscribe(EpisodeInfo, topics.EPISODE, self.gate.add_info, LATCHED)
        subscribe(BinauralAudio, topics.AUDIO, self.on_audio)
        subscribe(Odometry, topics.ODOM, lambda m: self.assembler.add_stamped(
            convert.nanoseconds_of(m.header.stamp), "odom", convert.pose_from_odometry(m)))
        separator_outputs = ((topics.SEPARATED_BINAURAL, "binaural", Spectrogram.SEPARATED_BINAURAL, (2, F, T)),
                             (topics.MONAURAL, "monaural", Spectrogram.MONAURAL_ESTIMATE, (F, T)),
                             (topics.REFINED, "refined", Spectrogram.REFINED, (F, T)))
        for topic, part, kind, shape in separator_outputs if separator else ():
            subscribe(Spectrogram, topic, lambda m, part=part, kind=kind, shape=shape: self.assembler.add(
                (m.episode_id, m.step), part, convert.spectrogram_from_msg(m, kind=kind, shape=shape)))
        if camera:
            # A robot camera's images of any size become the simulator's (core.robot.images).
            for topic, part, fit in ((topics.RGB, "rgb", fit_rgb), (topics.DEPTH, "depth", fit_depth)):
                subscribe(Image, topic, lambda m, part=part, fit=fit: self.assembler.add_stamped(
                    convert.nanoseconds_of(m.header.stamp), part, fit(convert.image_from_msg(m))))
        self.episode_id: str | None = None
        self.stopped = False  # far-target: the last command was Stop, so the next step is the last
        self.get_logger().info(f"ready: controller {self.controller.name}")

    def on_audio(self, msg: BinauralAudio) -> None:
        audio = convert.audio_from_msg(msg, sample_rate=DEFAULT_STFT.sample_rate, samples=DEFAULT_STFT.clip_samples)
        key = (msg.episode_id, msg.step)
        self.assembler.add(key, "audio", audio)
        self.assembler.bind(convert.nanoseconds_of(msg.header.stamp), key)

    def on_step(self, key: tuple[str, int], parts: dict, info: EpisodeInfo) -> None:
        episode_id, step = key
        if episode_id != self.episode_id:
            self.controller.reset(convert.episode_start_from_msg(info))
            self.episode_id, self.stopped = episode_id, False
        if step >= info.max_steps or self.stopped:
            return  # the episode's last observation: nothing to answer
        obs = ControllerObservation(
            step=np.array([step]), pose=parts["odom"][None], audio=parts["audio"][None],
            **{field: parts[part][None] if part in parts else None
               for field, part in (("separated_binaural", "binaural"), ("monaural", "monaural"),
                                   ("refined", "refined"), ("rgb", "rgb"), ("depth", "depth"))})
        action = self.controller.act(obs)
        self.stopped = action == STOP and info.task == "far_target"
        self.pub_command.publish(convert.command_msg(action, controller=self.controller.name, episode_id=episode_id,
                                                     step=step, stamp_ns=self.get_clock().now().nanoseconds))


def main(args=None):
    run_node(ControllerNode, args)


if __name__ == "__main__":
    main()
