"""recorder_node: records topics of the graph, as raw CDR, into a rosbag2 MCAP bag.

What is derived from other topics (spectrogram pictures, pcm-s16 tracks, the path, TF: io/derived.py)
is left out unless keep_derived is true: then no node builds it during the run, and ``m2h-derive``
adds the same topics to the bag afterwards. With keep_derived the recorder subscribes to them, and
derives TF and the tracks itself where the graph lacks their packages.

With live_view, the process also runs live_view_node, fed from the recorder's own subscriptions: a
client watching every topic then costs the graph no second delivery of each message (see
docs/reference/benchmarks.md).

Stopping it with Ctrl-C or SIGTERM closes the bag properly, so a recording is never lost."""

from collections.abc import Callable
from datetime import datetime
from pathlib import Path

import rclpy
from rclpy.node import Node

from m2h_ros.errors import BagError
from m2h_ros.io.bag import BagWriter
from m2h_ros.io.derived import Derived, derived_topics, offered_qos as derived_qos
from m2h_ros.io.topic_selection import TopicSelection
from m2h_ros.node_configs import RecorderConfig
from m2h_ros.ros.introspection import adapted_qos, definition_mismatch, offered_qos, offered_topics
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import subscription_events
from m2h_ros.ros.spin import run_node

# Parameter traffic of every node is noise in a recording of the pipeline.
IGNORED_TOPICS = frozenset({"/parameter_events"})
# Log lines come seconds before the first data (nodes loading models, the graph matching): they are held
# and written at the time of the first other message, each keeping its own stamp, so a bag's timeline
# starts with the run. More than this many held lines are written as they come.
LOG_TOPICS = frozenset({"/rosout"})
HELD_LOG_LINES = 10_000


class RecorderNode(Node):
    def __init__(self):
        super().__init__("recorder_node")
        self.config: RecorderConfig = declare_config(self, RecorderConfig)
        # First: a port already taken stops the start before a bag is created.
        self.live_view = None
        if self.config.live_view:
            from m2h_ros.nodes.live_view_node import LiveViewNode  # foxglove's server: only for those who ask

            self.live_view = LiveViewNode()
        output = self.config.output or f"runs/{datetime.now():%Y%m%d-%H%M%S}"
        if Path(output).exists() and not self.config.overwrite:
            # In what each startup takes: BagWriter's own message names its Python argument.
            raise BagError(f"bag {output} already exists: choose another output, or replace it with overwrite:=true "
                           "(ros2 launch), -p overwrite:=true (ros2 run) or --set recorder_node.overwrite=true "
                           "(run_pipeline.py)")
        self.writer = BagWriter(Path(output), flush_period_s=self.config.flush_period_s,
                                overwrite=self.config.overwrite, compression=self.config.compression)
        cfg = self.config
        self.selection = TopicSelection(cfg.topics, cfg.exclude, cfg.max_rate_hz)
        self.recorded: dict[str, str] = {}  # topic -> type name ("": seen, not recorded)
        self.counts: dict[str, int] = {}
        self.intervals: dict[str, int] = {}  # topic -> the shortest time (ns) between two of its messages kept
        self.last_kept: dict[str, int] = {}  # topic -> receive time (ns) of its last message kept
        self.rate_dropped: dict[str, int] = {}  # topic -> messages left out by its rate limit
        self.held: list[tuple[str, bytes]] | None = []  # log lines before the first data; None once written
        # TF and playable audio for the bag, derived from what is recorded (unless the graph publishes them);
        # without keep_derived, none of the derived topics (m2h-derive adds them from the raw ones).
        self.derived = Derived(namespace=self.get_namespace()) if cfg.keep_derived else None
        self.left_out = frozenset() if cfg.keep_derived else frozenset(derived_topics(self.get_namespace()))
        self.discovery = self.create_timer(self.config.discovery_period_s, self.discover_topics)
        self.flusher = self.create_timer(self.config.flush_period_s, self.writer.flush)  # idle stretches too
        self.listeners: list[Callable[[str, str, bytes], None]] = []  # (topic, type, cdr) of every message taken
        self.discover_topics()
        if self.live_view is not None:
            self.live_view.take_recorded(self)
        self.get_logger().info(f"recording to {self.writer.path}")

    @property
    def companions(self) -> tuple[Node, ...]:
        """The nodes run_node spins in this process beside this one (destroyed with it)."""
        return (self.live_view,) if self.live_view is not None else ()

    def discover_topics(self) -> None:
        for offer in offered_topics(self, known=self.recorded.keys() | IGNORED_TOPICS):
            topic, problem = offer.name, offer.problem
            if not self.selection.records(topic) or topic in self.left_out:
                self.recorded[topic] = ""
                continue
            if not problem:
                try:
                    self.writer.add_topic(topic, offer.type_name, offered_qos=offered_qos(self, topic))
                except BagError as exc:
                    problem = str(exc)
            if problem:
                self.get_logger().warning(f"not recording {topic}: {problem}")
                self.recorded[topic] = ""
                continue
            mismatch = definition_mismatch(self, topic, offer.type_name, self.writer.type_hash(topic),
                                           used="recorded in the bag", reader="a reader of the bag")
            if mismatch:
                self.get_logger().warning(mismatch)
            self.recorded[topic] = offer.type_name
            self.counts[topic] = 0
            interval = self.selection.min_interval_ns(topic)
            if interval is not None:
                self.intervals[topic], self.rate_dropped[topic] = interval, 0
            self.create_subscription(
                offer.msg_type, topic, lambda data, topic=topic: self.write(topic, data),
                adapted_qos(self, topic), raw=True,
                event_callbacks=subscription_events(self.get_logger(), topic))
            self.get_logger().info(f"recording {topic} [{offer.type_name}]")

    def write(self, topic: str, data: bytes) -> None:
        for listener in self.listeners:
            listener(topic, self.recorded[topic], data)
        now = self.get_clock().now().nanoseconds
        if self.held is not None:
            if topic in LOG_TOPICS and len(self.held) < HELD_LOG_LINES:
                self.held.append((topic, data))
                return
            self.write_held(now)
        interval = self.intervals.get(topic)
        if interval is not None:
            if now - self.last_kept.get(topic, now - interval) < interval:
                self.rate_dropped[topic] += 1
                return
            self.last_kept[topic] = now
        self.writer.write_raw(topic, self.recorded[topic], now, data)
        self.counts[topic] += 1
        if self.derived is None:
            return
        for extra, msgtype, extra_data in self.derived.feed(topic, self.recorded[topic], data):
            if extra in self.recorded or not self.selection.records(extra):  # the graph's own, or left out
                continue
            if extra not in self.counts:
                self.writer.add_topic(extra, msgtype, offered_qos=derived_qos(extra))
                self.counts[extra] = 0
            self.writer.write_raw(extra, msgtype, now, extra_data)
            self.counts[extra] += 1

    def write_held(self, now: int) -> None:
        held, self.held = self.held, None
        for topic, data in held:
            self.writer.write_raw(topic, self.recorded[topic], now, data)
            self.counts[topic] += 1

    def destroy_node(self) -> None:
        if self.live_view is not None:
            self.live_view.destroy_node()
        if self.held:  # a run that never got going: its log lines are all it has
            self.write_held(self.get_clock().now().nanoseconds)
        self.writer.close()
        total = sum(self.counts.values())
        logger = self.get_logger().name
        super().destroy_node()
        # Logged after the node is gone: the context may already be shut down (Ctrl-C), and a
        # destroyed node's logger no longer goes through its rosout publisher.
        dropped = ", ".join(f"{topic} {n}" for topic, n in self.rate_dropped.items() if n)
        rclpy.logging.get_logger(logger).info(f"closed {self.writer.path}: {total} messages on {len(self.counts)} topics"
                                              + (f"; left out by rate limits: {dropped}" if dropped else ""))


def main(args=None):
    run_node(RecorderNode, args)


if __name__ == "__main__":
    main()
