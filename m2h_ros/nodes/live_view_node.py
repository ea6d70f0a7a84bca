"""live_view_node: serves the graph, live, to Foxglove over its WebSocket protocol (foxglove-sdk), for
users without foxglove_bridge. Opt-in; bound to 127.0.0.1 by default.

Every topic is served as a ROS 2 channel (raw CDR, schema = the message definition, ``ros2msg``), so
Foxglove decodes each with no package of ours installed. Each audio topic (``m2h_msgs/BinauralAudio``)
also gets a derived ``<topic>/pcm`` track of Foxglove ``RawAudio`` (``pcm-s16``) for the Audio panel,
converted only while a client listens to it."""

import foxglove
import numpy as np
from foxglove import Channel, Schema
from foxglove.channels import RawAudioChannel
from foxglove.messages import RawAudio, Timestamp
from m2h_msgs.msg import BinauralAudio
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from m2h_ros.core.audio.pcm import pcm_int16
from m2h_ros.errors import LiveViewError
from m2h_ros.io.msg_defs import typestore
from m2h_ros.node_configs import LiveViewConfig
from m2h_ros.ros.introspection import adapted_qos, offered_topics
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import subscription_events
from m2h_ros.ros.spin import run_node

AUDIO_TYPE = "m2h_msgs/msg/BinauralAudio"
PCM_SUFFIX = "/pcm"
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
        self.channels: dict[str, Channel | None] = {}  # topic -> its channel; None: cannot be served
        self.pcm: dict[str, RawAudioChannel] = {}  # audio topic -> its derived pcm-s16 track
        self.discovery = self.create_timer(self.config.discovery_period_s, self.discover_topics)
        self.discover_topics()
        self.get_logger().info(f"serving the graph to Foxglove on ws://{self.config.host}:{self.server.port}")

    def discover_topics(self) -> None:
        for offer in offered_topics(self, known=self.channels.keys() | IGNORED_TOPICS, wanted=set(self.config.topics)):
            topic, problem, definition = offer.name, offer.problem, ""
            if not problem:
                try:
                    definition = typestore().generate_msgdef(offer.type_name, ros_version=2)[0]
                except Exception as exc:  # rosbags raises several types for a type it does not know
                    problem = f"no message definition of {offer.type_name} ({exc})"
            if problem:
                self.get_logger().warning(f"not serving {topic}: {problem}")
                self.channels[topic] = None
                continue
            self.channels[topic] = Channel(topic, message_encoding="cdr", context=self.sink_context, schema=Schema(
                name=offer.type_name, encoding="ros2msg", data=definition.encode()))
            if offer.type_name == AUDIO_TYPE:
                self.pcm[topic] = RawAudioChannel(topic + PCM_SUFFIX, context=self.sink_context)
            self.create_subscription(offer.msg_type, topic, lambda data, topic=topic: self.forward(topic, data),
                                     adapted_qos(self, topic), raw=True,
                                     event_callbacks=subscription_events(self.get_logger(), topic))
            self.get_logger().info(f"serving {topic} [{offer.type_name}]")

    def forward(self, topic: str, data: bytes) -> None:
        now = self.get_clock().now().nanoseconds
        self.channels[topic].log(data, log_time=now)
        pcm = self.pcm.get(topic)
        if pcm is not None and pcm.has_sinks():
            msg = deserialize_message(data, BinauralAudio)
            samples = np.asarray(msg.samples, dtype=np.float32)
            if not msg.channels or samples.size % msg.channels:  # a viewer skips a bad frame, never stops
                self.get_logger().warning(f"{topic}: {samples.size} samples do not fill {msg.channels} "
                                          "channels; no pcm track for this frame", throttle_duration_sec=10.0)
                return
            pcm.log(RawAudio(timestamp=Timestamp(msg.header.stamp.sec, msg.header.stamp.nanosec),
                             data=pcm_int16(samples.reshape(msg.channels, -1), gain=self.config.audio_gain), format="pcm-s16",
                             sample_rate=msg.sample_rate, number_of_channels=msg.channels), log_time=now)

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()


def main(args=None):
    run_node(LiveViewNode, args)


if __name__ == "__main__":
    main()
