"""evaluator_node: scores every step's refined estimate against the ground truth (the only node that
subscribes to /ground_truth) and every finished episode; publishes StepScore / EpisodeScore and keeps
the results table (Markdown + CSV + JSON, and the SI-SDR-vs-step plot at shutdown) in output_dir.

Scores come from m2h_ros.core.audio.scoring and m2h_ros.core.results, the same code in-process
evaluation and offline replay use: SI-SDR with the ground-truth phase (the paper's figure) and with
the mixture's phase (deployable), STFT distance, and SR / SPL for far-target episodes. The target's
spectrogram picture and pcm-s16 track are built only while something subscribes to them."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from m2h_msgs.msg import (AgentPose, BinauralAudio, EpisodeInfo, EpisodeScore, GroundTruth, MotionCommand, Spectrogram,
                          StepScore)
from rclpy.node import Node
from sensor_msgs.msg import Image

from m2h_ros import topics
from m2h_ros.core.audio.scoring import score_magnitude
from m2h_ros.core.audio.stft import DEFAULT_STFT, stft
from m2h_ros.core.results import HELD, EpisodeResult, EpisodeTracker, markdown_table, summarize, write_results
from m2h_ros.node_configs import EvaluatorConfig
from m2h_ros.ros import convert
from m2h_ros.io.derived import spectrogram_image_cdr
from m2h_ros.ros.introspection import raw_audio_publisher
from m2h_ros.ros.on_demand import OnDemand, on_demand_summary
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import LATCHED, STEP, publisher_events, subscription_events
from m2h_ros.ros.spin import run_node
from m2h_ros.ros.sync import EpisodeGate, StepAssembler

N, F, T = DEFAULT_STFT.clip_samples, DEFAULT_STFT.n_freq, DEFAULT_STFT.n_frames
WRITE_PERIOD_S = 10.0


class EvaluatorNode(Node):
    def __init__(self):
        super().__init__("evaluator_node")
        self.config: EvaluatorConfig = declare_config(self, EvaluatorConfig)
        self.gate = EpisodeGate(self.on_step)  # steps wait for their episode's info
        self.assembler = StepAssembler({"truth", "refined", "audio", "pose"}, self.gate.step)
        self.pub_step = self.create_publisher(StepScore, topics.STEP_SCORE, STEP,
                                              event_callbacks=publisher_events(self.get_logger(), topics.STEP_SCORE))
        self.pub_episode = self.create_publisher(EpisodeScore, topics.EPISODE_SCORE, STEP,
                                                 event_callbacks=publisher_events(self.get_logger(),
                                                                                  topics.EPISODE_SCORE))
        self.pub_pcm = raw_audio_publisher(self, topics.GROUND_TRUTH, STEP)  # where foxglove_msgs is installed
        self.pub_target_image = OnDemand(self.create_publisher(
            Image, topics.TARGET_IMAGE, STEP, event_callbacks=publisher_events(self.get_logger(), topics.TARGET_IMAGE)))

        def subscribe(kind, topic, callback, qos=STEP):
            self.create_subscription(kind, topic, callback, qos,
                                     event_callbacks=subscription_events(self.get_logger(), topic))

        subscribe(EpisodeInfo, topics.EPISODE, self.gate.add_info, LATCHED)
        subscribe(GroundTruth, topics.GROUND_TRUTH, lambda m: self.assembler.add(
            (m.episode_id, m.step), "truth", m))
        subscribe(Spectrogram, topics.REFINED, lambda m: self.assembler.add(
            (m.episode_id, m.step), "refined", convert.spectrogram_from_msg(m, kind=Spectrogram.REFINED, shape=(F, T))))
        subscribe(BinauralAudio, topics.AUDIO, lambda m: self.assembler.add(
            (m.episode_id, m.step), "audio", convert.audio_from_msg(m, sample_rate=DEFAULT_STFT.sample_rate,
                                                                    samples=N)))
        subscribe(AgentPose, topics.AGENT_POSE, lambda m: self.assembler.add((m.episode_id, m.step), "pose", m))
        subscribe(MotionCommand, topics.COMMAND, lambda m: self.controllers.setdefault(m.episode_id, m.controller))
        self.trackers: dict[str, EpisodeTracker] = {}
        self.controllers: dict[str, str] = {}
        self.results: list[EpisodeResult] = []
        self.output = Path(self.config.output_dir) if self.config.output_dir else None
        self.written_at = -WRITE_PERIOD_S
        self.get_logger().info(f"ready: results to {self.output or '(nowhere: output_dir is empty)'}")

    def on_step(self, key: tuple[str, int], parts: dict, info: EpisodeInfo) -> None:
        episode_id, step = key
        truth_msg = parts["truth"]
        truth = convert.truth_from_msg(truth_msg, samples=N)
        scores = score_magnitude(parts["refined"][None], parts["audio"][None], truth, config=DEFAULT_STFT)
        values = dict(si_sdr=float(scores.si_sdr[0]), si_sdr_mixture_phase=float(scores.si_sdr_mixture_phase[0]),
                      stft_distance=float(scores.stft_distance[0]))
        stamp = self.get_clock().now().nanoseconds
        self.pub_step.publish(convert.step_score_msg(**values, geodesic_distance=truth_msg.geodesic_distance,
                                                     episode_id=episode_id, step=step, stamp_ns=stamp))
        truth_stamp = convert.nanoseconds_of(truth_msg.header.stamp)
        self.pub_target_image.publish(lambda: spectrogram_image_cdr(
            np.abs(stft(truth.target_monaural[0], config=DEFAULT_STFT)), stamp_ns=truth_stamp))
        if self.pub_pcm is not None:
            self.pub_pcm.send(truth.target_monaural, truth_msg.sample_rate, truth_stamp)
        if step == 0:
            result = EpisodeResult(episode_id=episode_id, controller=self.controllers.get(episode_id, ""),
                                   task=info.task, sound_split=info.split, scene_id=info.scene_id,
                                   target_class=info.target_class, shortest_path=truth_msg.geodesic_distance)
            self.trackers[episode_id] = EpisodeTracker(result, convert.position_of(parts["pose"]))
        tracker = self.trackers.get(episode_id)
        if tracker is None:
            self.get_logger().warning(f"{episode_id} step {step}: its step 0 was never seen; not scored")
            return
        if step > 0:  # the pose tells which action (or hold) brought the robot here
            tracker.act(step - 1, parts["pose"].last_action)
        tracker.observe(step, **values, position=convert.position_of(parts["pose"]),
                        at_target=truth_msg.at_target)
        if truth_msg.last_step:
            self.finish(episode_id)

    def finish(self, episode_id: str) -> None:
        tracker = self.trackers.pop(episode_id)
        tracker.result.controller = self.controllers.get(episode_id, "")
        result = tracker.finish()
        self.results.append(result)
        self.pub_episode.publish(convert.episode_score_msg(result, stamp_ns=self.get_clock().now().nanoseconds))
        held = result.actions.count(HELD)
        self.get_logger().info(f"{episode_id}: SI-SDR {result.final('si_sdr'):.2f} dB (GT phase), "
                               f"{result.final('si_sdr_mixture_phase'):.2f} dB (mixture phase) after "
                               f"{result.steps} steps" + (f", {held} held" if held else ""))
        # Tables of every episode so far: at the first episode, then at most every WRITE_PERIOD_S
        # (rewriting them per episode would grow quadratically over a long run); all at shutdown.
        if self.output is not None and time.monotonic() - self.written_at > WRITE_PERIOD_S:
            self.write(final=False)
            self.written_at = time.monotonic()

    def completeness(self, *, final: bool) -> str:
        """How much of the run the tables hold: '' for a whole run, else what a reader must know."""
        scored, planned = len(self.results), self.config.episodes
        of = f" of {planned}" if planned else ""
        if not final:
            return f"in progress: {scored}{of} episodes scored so far"
        if (planned and scored < planned) or self.trackers:
            return f"partial: {scored}{of} episodes scored, the run ended early"
        return ""

    def write(self, *, final: bool) -> dict[str, Path]:
        state = self.completeness(final=final)
        return write_results(self.results, self.output, title="m2h_ros pipeline run" + (f" ({state})" if state else ""),
                             plot=final, meta={"episodes_planned": self.config.episodes,
                                               "episodes_scored": len(self.results), "complete": not state})

    def destroy_node(self) -> None:
        print(f"evaluator_node: {on_demand_summary([self.pub_target_image, self.pub_pcm])}", flush=True)
        if self.output is not None and self.results:
            paths = self.write(final=True)
            state = self.completeness(final=True)
            # The table itself too: under ros2 launch this output is all a user sees of the scores.
            print(f"evaluator: {len(self.results)} episodes scored{f' ({state.upper()})' if state else ''} -> "
                  f"{paths['markdown']}\n{markdown_table(summarize(self.results))}", flush=True)
        super().destroy_node()


def main(args=None):
    run_node(EvaluatorNode, args)


if __name__ == "__main__":
    main()
