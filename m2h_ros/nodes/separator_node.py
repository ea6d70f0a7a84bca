"""separator_node: f^B -> f^M -> f^R on each step's binaural audio; publishes the separated binaural,
monaural and refined spectrograms, and audio to listen to (``audio_output``): by default the listener
output (the target's early image at both ears; ``audio_channels: mono`` for their mean), or f^B's mask on
each ear of the mixture, or the refined estimate with the mixture's phase. The spectrogram pictures and the
audio's pcm-s16 track are built only while something subscribes to them (ros/on_demand.py); a bag gets them
from ``m2h-derive`` otherwise.

The refiner's memory restarts whenever the episode id changes. The target class comes from the
episode's EpisodeInfo (a frame waits until its episode's info arrives) or, for a live microphone
with no simulator (scripts/play_binaural.py or a real driver), from the target_class parameter.
Unusable audio (wrong rate, channel count or length, NaN) ends the node with an error naming it."""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads: idle threads must not spin

import numpy as np  # noqa: E402
import torch  # noqa: E402
from m2h_msgs.msg import BinauralAudio, EpisodeInfo, Spectrogram  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from m2h_ros import topics  # noqa: E402
from m2h_ros.core.audio.stft import stft  # noqa: E402
from m2h_ros.io.derived import spectrogram_image_cdr  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.device import resolve_device  # noqa: E402
from m2h_ros.models.listener import DEFAULT_LISTENER_CHECKPOINT, load_listener  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.models.threads import inference_threads  # noqa: E402
from m2h_ros.node_configs import SeparatorNodeConfig  # noqa: E402
from m2h_ros.ros import convert  # noqa: E402
from m2h_ros.ros.introspection import raw_audio_publisher  # noqa: E402
from m2h_ros.ros.on_demand import OnDemand, on_demand_summary  # noqa: E402
from m2h_ros.ros.params import declare_config  # noqa: E402
from m2h_ros.ros.qos import LATCHED, STEP, publisher_events, subscription_events  # noqa: E402
from m2h_ros.ros.spin import run_node  # noqa: E402

MAX_WAITING_FRAMES = 32  # frames kept while their episode's info has not arrived


class SeparatorNode(Node):
    def __init__(self):
        super().__init__("separator_node")
        self.config: SeparatorNodeConfig = declare_config(self, SeparatorNodeConfig)
        self.threads = self.config.torch_threads or inference_threads(1)
        torch.set_num_threads(self.threads)
        device = resolve_device(self.config.device, field="separator_node.device")
        loaded = load_separator(self.config.checkpoint or DEFAULT_SEPARATOR_CHECKPOINT, map_location=device)
        listener = None
        if self.config.audio_output == "listener":
            listener = load_listener(self.config.listener_checkpoint or DEFAULT_LISTENER_CHECKPOINT, map_location=device)
        self.runner = SeparatorRunner(loaded, 1, listener=listener)
        self.binaural = self.config.audio_channels == "binaural"
        self.stft = loaded.stft
        if self.config.target_class:
            loaded.class_index(self.config.target_class)  # an unknown class fails now, not per frame

        def publisher(kind, topic):
            return self.create_publisher(kind, topic, STEP, event_callbacks=publisher_events(self.get_logger(), topic))

        self.pub_binaural = publisher(Spectrogram, topics.SEPARATED_BINAURAL)
        self.pub_monaural = publisher(Spectrogram, topics.MONAURAL)
        self.pub_refined = publisher(Spectrogram, topics.REFINED)
        self.pub_audio = publisher(BinauralAudio, topics.SEPARATED_AUDIO)
        self.pub_pcm = raw_audio_publisher(self, topics.SEPARATED_AUDIO, STEP)  # where foxglove_msgs is installed
        self.pub_images = {topic: OnDemand(publisher(Image, topic)) for topic in (
            topics.MIXTURE_IMAGE, topics.BINAURAL_IMAGE, topics.MONAURAL_IMAGE, topics.REFINED_IMAGE)}
        self.create_subscription(EpisodeInfo, topics.EPISODE, self.on_episode, LATCHED,
                                 event_callbacks=subscription_events(self.get_logger(), topics.EPISODE))
        self.create_subscription(BinauralAudio, topics.AUDIO, self.on_audio, STEP,
                                 event_callbacks=subscription_events(self.get_logger(), topics.AUDIO))
        self.classes: dict[str, str] = {}  # episode id -> target class
        self.waiting: list[BinauralAudio] = []
        self.episode_id: str | None = None
        self.latencies: list[float] = []
        self.get_logger().info(f"ready: separator {loaded.path.name} ({loaded.config.summary}), "
                               f"on {device}, {self.threads} torch thread(s)")

    def on_episode(self, msg: EpisodeInfo) -> None:
        self.classes[msg.episode_id] = msg.target_class
        waiting, self.waiting = self.waiting, []
        for frame in waiting:
            self.on_audio(frame)

    def on_audio(self, msg: BinauralAudio) -> None:
        target = self.config.target_class or self.classes.get(msg.episode_id)
        if target is None:
            self.waiting = [*self.waiting, msg][-MAX_WAITING_FRAMES:]
            return
        started = time.perf_counter()
        mixture = convert.audio_from_msg(msg, sample_rate=self.stft.sample_rate, samples=self.stft.clip_samples)
        reset = msg.episode_id != self.episode_id
        self.episode_id = msg.episode_id
        classes = self.runner.class_indices([target])
        out = self.runner.step(mixture[None], classes, np.array([reset]))
        stamp = convert.nanoseconds_of(msg.header.stamp)
        tag = dict(episode_id=msg.episode_id, step=msg.step, stamp_ns=stamp)
        self.pub_binaural.publish(convert.spectrogram_msg(out.binaural[0], kind=Spectrogram.SEPARATED_BINAURAL,
                                                          layout="CFT", stft=self.stft, **tag))
        self.pub_monaural.publish(convert.spectrogram_msg(out.monaural[0], kind=Spectrogram.MONAURAL_ESTIMATE,
                                                          layout="FT", stft=self.stft, **tag))
        self.pub_refined.publish(convert.spectrogram_msg(out.refined[0], kind=Spectrogram.REFINED, layout="FT",
                                                         stft=self.stft, **tag))
        if self.config.audio_output == "listener":
            waveform = self.runner.listen(mixture[None], classes, binaural=self.binaural)[0]
        else:
            waveform = out.waveform(mixture[None], config=self.stft, output=self.config.audio_output,
                                    binaural=self.binaural)[0]
        waveform = waveform.reshape(-1, waveform.shape[-1])  # (channels, samples)
        self.pub_audio.publish(convert.audio_msg(waveform, sample_rate=self.stft.sample_rate, **tag))
        self.latencies.append(time.perf_counter() - started)
        # Pictures to look at and audio to hear (for whoever subscribes), after all the controller waits for.
        if self.pub_pcm is not None:
            self.pub_pcm.send(waveform, self.stft.sample_rate, stamp)
        self.pub_images[topics.MIXTURE_IMAGE].publish(
            lambda: spectrogram_image_cdr(np.abs(out.mixture[1][0] if out.mixture else stft(mixture, config=self.stft)),
                                          stamp_ns=stamp))
        for topic, magnitude in ((topics.BINAURAL_IMAGE, out.binaural[0]), (topics.MONAURAL_IMAGE, out.monaural[0]),
                                 (topics.REFINED_IMAGE, out.refined[0])):
            self.pub_images[topic].publish(lambda magnitude=magnitude: spectrogram_image_cdr(magnitude, stamp_ns=stamp))

    def destroy_node(self) -> None:
        if self.latencies:
            ms = 1000 * np.array(self.latencies)
            # Printed, not logged: at Ctrl-C the context (and its rosout) may already be gone.
            print(f"separator_node: {len(ms)} steps, latency per step (message in to all out) "
                  f"p50 {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms", flush=True)
        print(f"separator_node: {on_demand_summary([*self.pub_images.values(), self.pub_pcm])}", flush=True)
        super().destroy_node()


def main(args=None):
    run_node(SeparatorNode, args)


if __name__ == "__main__":
    main()
