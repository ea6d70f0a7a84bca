"""live_view_node: serves the graph, live, to Foxglove over its WebSocket protocol (foxglove-sdk), for
users without foxglove_bridge. Opt-in; bound to 127.0.0.1 by default.

Every topic is served as a ROS 2 channel (raw CDR, schema = the message definition, ``ros2msg``), so
Foxglove decodes each with no package of ours installed. The products derived from the raw topics
(io/derived.py) are made here, each only while a client shows it: the spectrogram pictures, the audio as
Foxglove ``RawAudio`` (``<audio topic>/pcm``, ``pcm-s16``) and the path, with the builders the nodes
use, so byte for byte what a node would send. The nodes' own copies of them are not subscribed to:
built here, they stay off the lockstep of the pipeline's step (the separator's step waits for its
pictures) and cost the graph no extra delivery (see docs/reference/benchmarks.md). The TF tree (``/tf``,
``/tf_static``) is made here too unless the graph publishes it, as a robot's own stack does. A client
that subscribes to a latched topic (the map, the static frames, the episode) gets its last message at
once, as a late ROS subscriber would.

As foxglove_bridge does, the node subscribes in ROS only to what some client watches (and to the latched
topics, to have their last message): a live view that nobody opens costs the graph nothing. Run in the
recorder's process (recorder_node's live_view), it takes every topic the recorder records from the
recorder's subscription rather than its own."""

import foxglove
from foxglove import Channel, Schema
from foxglove.websocket import ServerListener
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy
from rclpy.subscription import Subscription

from m2h_ros.errors import LiveViewError
from m2h_ros import topics
from m2h_ros.io.derived import TF, TF_STATIC, Derived, absolute
from m2h_ros.io.msg_defs import ensure_known, typestore
from m2h_ros.node_configs import LiveViewConfig
from m2h_ros.ros.graph import PIPELINE_TOPICS
from m2h_ros.ros.introspection import OfferedTopic, adapted_qos, definition_mismatch, offered_topics
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import subscription_events
from m2h_ros.ros.spin import run_node

IGNORED_TOPICS = frozenset({"/parameter_events"})
DEMAND_PERIOD_S = 0.1  # how soon a client's (un)subscription is followed in ROS


class LatchedReplay(ServerListener):
    """Sends a latched topic's last message when a client subscribes to it (to every subscriber of the
    channel: one repeat of a state message is harmless)."""

    def __init__(self):
        self.last: dict[str, tuple[Channel, bytes]] = {}  # topic -> its channel and last message

    def on_subscribe(self, client, channel) -> None:
        kept = self.last.get(channel.topic)
        if kept is not None:
            kept[0].log(kept[1])


class LiveViewNode(Node):
    def __init__(self):
        super().__init__("live_view_node")
        self.config: LiveViewConfig = declare_config(self, LiveViewConfig)
        self.sink_context = foxglove.Context()  # its own: no other channel of the process reaches the clients
        self.replay = LatchedReplay()
        try:
            self.server = foxglove.start_server(name="m2h_ros", host=self.config.host, port=self.config.port,
                                                context=self.sink_context, server_listener=self.replay)
        except RuntimeError as exc:  # the SDK's FoxgloveError: port taken, unknown address
            raise LiveViewError(f"cannot serve on {self.config.host}:{self.config.port}: {exc}") from exc
        self.channels: dict[str, Channel | None] = {}  # graph topic -> its channel; None: cannot be served
        self.derived = Derived(namespace=self.get_namespace(), views=True)
        self.derived_channels = {topic: self.channel(topic, type_name)
                                 for topic, type_name in self.derived.topics().items()}
        self.derived_sources = self.derived.sources()
        # Made here even where a node publishes them: the pipeline's own products, not a robot's frames.
        self.made_here = frozenset(self.derived_channels) - {TF, TF_STATIC}
        namespace = self.get_namespace()
        self.state_topics = {absolute(name, namespace) for name in topics.STATE}
        self.pipeline_topics = {absolute(name, namespace) for name in PIPELINE_TOPICS}
        self.latched: set[str] = {TF_STATIC}
        self.offers: dict[str, OfferedTopic] = {}  # served graph topic -> its offer (type), subscribed while watched
        self.subscribed: dict[str, Subscription] = {}
        self.recorder = None  # a RecorderNode of this process whose recorded topics come through take_recorded
        self.discovery = self.create_timer(self.config.discovery_period_s, self.discover_topics)
        self.create_timer(DEMAND_PERIOD_S, self.follow_demand)
        self.discover_topics()
        self.get_logger().info(f"serving the graph to Foxglove on ws://{self.config.host}:{self.server.port}")

    def channel(self, topic: str, type_name: str) -> Channel:
        store = typestore()
        ensure_known(store, type_name)  # a robot driver's own type: from its installed package
        mismatch = definition_mismatch(self, topic, type_name, store.hash_rihs01(type_name),
                                       used="served to Foxglove", reader="Foxglove")
        if mismatch:
            self.get_logger().warning(mismatch)
        definition = store.generate_msgdef(type_name, ros_version=2)[0]
        return Channel(topic, message_encoding="cdr", context=self.sink_context,
                       schema=Schema(name=type_name, encoding="ros2msg", data=definition.encode()))

    def discover_topics(self) -> None:
        for offer in offered_topics(self, known=self.channels.keys() | IGNORED_TOPICS, wanted=set(self.config.topics)):
            topic, problem = offer.name, offer.problem
            if topic in self.made_here:
                self.channels[topic] = None  # served as made here; the node's copy is never subscribed to
                continue
            if not problem:
                try:
                    channel = self.channel(topic, offer.type_name)
                except Exception as exc:  # rosbags raises several types for a type it does not know
                    problem = f"no message definition of {offer.type_name} ({exc})"
            if problem:
                self.get_logger().warning(f"not serving {topic}: {problem}")
                self.channels[topic] = None
                continue
            derived = self.derived_channels.pop(topic, None)
            if derived is not None:  # the graph publishes it (tf2_msgs installed): serve that one
                derived.close()
            self.channels[topic] = channel
            if self.is_state(topic):
                self.latched.add(topic)
            self.offers[topic] = offer
            self.get_logger().info(f"serving {topic} [{offer.type_name}]")
        self.follow_demand()

    def is_state(self, topic: str) -> bool:
        """Latched: the pipeline's state topics (the map, the static frames, the episode), and another
        package's topic whose every publisher is transient-local (a map server's map, a robot description)."""
        if topic in self.state_topics:
            return True
        if topic in self.pipeline_topics:  # a step stream: transient-local for lag, not as state
            return False
        offers = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
        return bool(offers) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offers)

    def watched(self, topic: str) -> bool:
        """Whether ``topic`` is needed in ROS: latched, shown by a client, or the source of a derived topic
        a client shows."""
        if topic in self.latched or self.channels[topic].has_sinks():
            return True
        return any(channel.has_sinks() for derived, channel in self.derived_channels.items()
                   if self.derived_sources.get(derived) == topic)

    def take_recorded(self, recorder) -> None:
        """From now on, every topic ``recorder`` records comes from its subscription, not one of ours."""
        self.recorder = recorder
        recorder.listeners.append(self.from_recorder)
        self.follow_demand()

    def from_recorder(self, topic: str, type_name: str, data: bytes) -> None:
        if topic in self.offers and self.watched(topic):
            self.forward(topic, type_name, data)

    def follow_demand(self) -> None:
        """Subscribes in ROS to the served topics that are watched now (unless the recorder takes them),
        and unsubscribes from the others."""
        recorded = self.recorder.recorded if self.recorder is not None else {}
        for topic, offer in self.offers.items():
            needed = self.watched(topic) and not recorded.get(topic)
            if needed == (topic in self.subscribed):
                continue
            if topic in self.subscribed:
                self.destroy_subscription(self.subscribed.pop(topic))
                continue
            self.subscribed[topic] = self.create_subscription(
                offer.msg_type, topic, lambda data, topic=topic, kind=offer.type_name: self.forward(topic, kind, data),
                adapted_qos(self, topic), raw=True, event_callbacks=subscription_events(self.get_logger(), topic))

    def forward(self, topic: str, type_name: str, data: bytes) -> None:
        now = self.get_clock().now().nanoseconds
        self.log(topic, self.channels[topic], data, now)
        if not any(channel.has_sinks() for channel in self.derived_channels.values()):
            return
        for extra, _, extra_data in self.derived.feed(topic, type_name, data):
            channel = self.derived_channels.get(extra)
            if channel is not None:
                self.log(extra, channel, extra_data, now)

    def log(self, topic: str, channel: Channel, data: bytes, now: int) -> None:
        channel.log(data, log_time=now)
        if topic in self.latched:
            self.replay.last[topic] = (channel, data)

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()


def main(args=None):
    run_node(LiveViewNode, args)


if __name__ == "__main__":
    main()
