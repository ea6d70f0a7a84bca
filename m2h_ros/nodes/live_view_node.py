"""live_view_node: serves the graph, live, to Foxglove over its WebSocket protocol (foxglove-sdk), for
users without foxglove_bridge. Opt-in; bound to 127.0.0.1 by default.

Every topic is served as a ROS 2 channel (raw CDR, schema = the message definition, ``ros2msg``), so
Foxglove decodes each with no package of ours installed. Beside them, the topics a bag gets from the
recorder (io/derived.py), made the same way, unless the graph publishes them itself: the TF tree
(``/tf``, ``/tf_static``) and the audio as Foxglove ``RawAudio`` (``<audio topic>/pcm``, ``pcm-s16``),
computed only while a client listens to one of them."""

import foxglove
from foxglove import Channel, Schema
from rclpy.node import Node

from m2h_ros.errors import LiveViewError
from m2h_ros.io.derived import TF, TF_STATIC, Derived
from m2h_ros.io.msg_defs import typestore
from m2h_ros.node_configs import LiveViewConfig
from m2h_ros.ros.introspection import adapted_qos, offered_topics
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import subscription_events
from m2h_ros.ros.spin import run_node

IGNORED_TOPICS = frozenset({"/parameter_events"})


class LiveViewNode(Node):
    def __init__(self):
        super().__init__("live_view_node")
        self.config: LiveViewConfig = declare_config(self, LiveViewConfig)
        self.sink_context = foxglove.Context()  # its own: no other channel of the process reaches the clients
        try:
            self.server = foxglove.start_server(name="m2h_ros", host=self.config.host, port=self.config.port,
                                                context=self.sink_context)
        except RuntimeError as exc:  # the SDK's FoxgloveError: port taken, unknown address
            raise LiveViewError(f"cannot serve on {self.config.host}:{self.config.port}: {exc}") from exc
        self.channels: dict[str, Channel | None] = {}  # graph topic -> its channel; None: cannot be served
        self.derived = Derived(namespace=self.get_namespace())
        self.derived_channels = {topic: self.channel(topic, type_name)
                                 for topic, type_name in self.derived.topics().items()}
        self.tf_static: bytes | None = None  # sent again with each /tf: a client that joins late still gets it
        self.discovery = self.create_timer(self.config.discovery_period_s, self.discover_topics)
        self.discover_topics()
        self.get_logger().info(f"serving the graph to Foxglove on ws://{self.config.host}:{self.server.port}")

    def channel(self, topic: str, type_name: str) -> Channel:
        definition = typestore().generate_msgdef(type_name, ros_version=2)[0]
        return Channel(topic, message_encoding="cdr", context=self.sink_context,
                       schema=Schema(name=type_name, encoding="ros2msg", data=definition.encode()))

    def discover_topics(self) -> None:
        for offer in offered_topics(self, known=self.channels.keys() | IGNORED_TOPICS, wanted=set(self.config.topics)):
            topic, problem = offer.name, offer.problem
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
            self.create_subscription(offer.msg_type, topic,
                                     lambda data, topic=topic, kind=offer.type_name: self.forward(topic, kind, data),
                                     adapted_qos(self, topic), raw=True,
                                     event_callbacks=subscription_events(self.get_logger(), topic))
            self.get_logger().info(f"serving {topic} [{offer.type_name}]")

    def forward(self, topic: str, type_name: str, data: bytes) -> None:
        now = self.get_clock().now().nanoseconds
        self.channels[topic].log(data, log_time=now)
        if not any(channel.has_sinks() for channel in self.derived_channels.values()):
            return
        for extra, _, extra_data in self.derived.feed(topic, type_name, data):
            channel = self.derived_channels.get(extra)
            if channel is None:
                continue
            if extra == TF_STATIC:
                self.tf_static = extra_data
            channel.log(extra_data, log_time=now)
            if extra == TF and self.tf_static is not None and TF_STATIC in self.derived_channels:
                self.derived_channels[TF_STATIC].log(self.tf_static, log_time=now)

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()


def main(args=None):
    run_node(LiveViewNode, args)


if __name__ == "__main__":
    main()
