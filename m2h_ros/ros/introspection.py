"""Message classes by type name, the topics a listener to the whole graph can take, the QoS a subscriber
should use to hear every publisher, and the QoS publishers offer (as rosbags records it)."""

import importlib
from collections.abc import Collection, Container, Iterator
from dataclasses import dataclass

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from m2h_ros.io.derived import pcm_topic
from m2h_ros.io.msg_defs import RAW_AUDIO
from m2h_ros.ros.convert import raw_audio_msg
from m2h_ros.ros.on_demand import OnDemand
from m2h_ros.ros.qos import RECORD


def message_class(type_name: str) -> type:
    """``pkg/msg/Name`` -> the generated Python class."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


@dataclass(frozen=True)
class OfferedTopic:
    """A topic with a publisher: its type and class, or why it cannot be taken (``problem``)."""

    name: str
    type_name: str = ""
    msg_type: type | None = None
    problem: str = ""


def offered_topics(node: Node, *, known: Container[str], wanted: Collection[str] = ()) -> Iterator[OfferedTopic]:
    """The topics not in ``known`` (and in ``wanted``, unless empty) that a publisher offers now.

    A topic seen only through its subscribers has no offer to adapt to (a best-effort subscription would
    drop messages under load): it is left for a later call, once a publisher exists, as rosbag2 does."""
    for topic, types in node.get_topic_names_and_types():
        if topic in known or (wanted and topic not in wanted) or not node.get_publishers_info_by_topic(topic):
            continue
        if len(types) != 1:
            yield OfferedTopic(topic, problem=f"it carries several types {types}")
            continue
        try:
            yield OfferedTopic(topic, types[0], message_class(types[0]))
        except (ImportError, AttributeError, ValueError):
            yield OfferedTopic(topic, types[0], problem=f"type {types[0]} is not importable")


def definition_mismatch(node: Node, topic: str, type_name: str, definition_hash: str, *, used: str,
                        reader: str) -> str:
    """A warning when the definition ``used`` for ``topic`` (an installed package's, for a type this project
    does not define) hashes otherwise than its publishers' (RIHS01): the bytes pass all the same, but
    ``reader`` would decode them with the wrong fields. Empty when they agree or no publisher says."""
    offered = {str(info.topic_type_hash) for info in node.get_publishers_info_by_topic(topic)}
    if not offered or definition_hash in offered:
        return ""
    return (f"{topic}: the definition of {type_name} {used} hashes to {definition_hash}, its publishers' to "
            f"{', '.join(sorted(offered))}: {reader} will misread it (an installed package differs from the "
            "publisher's)")


def optional_message_class(type_name: str) -> type | None:
    """The class where its package is installed, else None (the PyPI wheels lack tf2_msgs and
    foxglove_msgs; a ROS 2 install may have them)."""
    try:
        return message_class(type_name)
    except (ImportError, AttributeError):
        return None


class RawAudioPublisher(OnDemand):
    """pcm-s16 RawAudio on ``<audio topic>/pcm``, built only while subscribed."""

    def __init__(self, node: Node, audio_topic: str, qos: QoSProfile, raw_audio: type) -> None:
        super().__init__(node.create_publisher(raw_audio, pcm_topic(audio_topic), qos))
        self.raw_audio = raw_audio

    def send(self, samples, sample_rate: int, stamp_ns: int) -> None:
        self.publish(lambda: raw_audio_msg(self.raw_audio, samples, sample_rate=sample_rate, stamp_ns=stamp_ns))


def raw_audio_publisher(node: Node, audio_topic: str, qos: QoSProfile) -> RawAudioPublisher | None:
    """Where foxglove_msgs is installed, the publisher of ``audio_topic``'s pcm-s16 track; else None (the
    recorder or ``m2h-derive`` writes the same track into the bag)."""
    raw_audio = optional_message_class(RAW_AUDIO)
    return None if raw_audio is None else RawAudioPublisher(node, audio_topic, qos, raw_audio)


def adapted_qos(node: Node, topic: str) -> QoSProfile:
    """Like rosbag2: reliable / transient-local only when every current publisher offers it."""
    infos = node.get_publishers_info_by_topic(topic)
    qos = QoSProfile(history=RECORD.history, depth=RECORD.depth,
                     reliability=RECORD.reliability, durability=RECORD.durability)
    if infos and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos):
        qos.reliability = ReliabilityPolicy.RELIABLE
    if infos and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos


def _qos_time(duration) -> QosTime:
    sec, nsec = divmod(duration.nanoseconds, 10**9)
    return QosTime(sec, nsec)


def offered_qos(node: Node, topic: str) -> list[Qos]:
    """The QoS profile of every current publisher of ``topic`` (rmw's enum values are rosbags')."""
    return [Qos(history=QosHistory(int(q.history)), depth=q.depth, reliability=QosReliability(int(q.reliability)),
                durability=QosDurability(int(q.durability)), deadline=_qos_time(q.deadline),
                lifespan=_qos_time(q.lifespan), liveliness=QosLiveliness(int(q.liveliness)),
                liveliness_lease_duration=_qos_time(q.liveliness_lease_duration),
                avoid_ros_namespace_conventions=q.avoid_ros_namespace_conventions)
            for q in (info.qos_profile for info in node.get_publishers_info_by_topic(topic))]
