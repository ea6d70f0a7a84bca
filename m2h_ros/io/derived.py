"""Topics a recording gets beside the recorded ones, for tools that expect standard types: the robot's TF
tree (tf2_msgs/TFMessage on /tf and /tf_static, from the odometry and the agent's pose) and audio to
listen to (foxglove_msgs/RawAudio, pcm-s16, from the mixture, the separated estimate and the target).

ROS-free: it works on serialized CDR, so the recorder can write it where neither tf2_msgs nor
foxglove_msgs is installed (the bag writer knows their released definitions, see io/msg_defs.py), and a
live view can serve it the same way. Where the graph publishes a topic itself (tf2_msgs or foxglove_msgs
installed), the recorder records that one and leaves this one out.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from m2h_ros import topics
from m2h_ros.core.audio.pcm import pcm_int16
from m2h_ros.core.world.frames import Transform, base_transform, quaternion_yaw, static_transforms
from m2h_ros.io.msg_defs import RAW_AUDIO, TF_MESSAGE, typestore

TF, TF_STATIC = topics.TF, topics.TF_STATIC
PCM_SUFFIX = "/pcm"  # RawAudio of an audio topic: the same name with this suffix
# Float audio to pcm-s16, in bags and in the live view alike (mixtures peak near 20; full scale is 25).
PCM_GAIN = 0.04
_INFINITE = QosTime(9223372036, 854775807)  # rmw's "infinite" duration, as a publisher's QoS reports it


def offered_qos(topic: str) -> list[Qos]:
    """The QoS a bag lists for a derived topic (``ros2 bag play`` republishes with it): /tf_static latched
    (reliable, transient local, last one) as tf2's static broadcaster offers it, the rest reliable."""
    latched = topic == TF_STATIC
    return [Qos(QosHistory.KEEP_LAST, 1 if latched else 100, QosReliability.RELIABLE,
                QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
                _INFINITE, _INFINITE, QosLiveliness.AUTOMATIC, _INFINITE, False)]


def absolute(name: str, namespace: str = "") -> str:
    """A pipeline topic name as the graph resolves it in ``namespace``."""
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}" if namespace.strip("/") else f"/{name}"


def pcm_topic(audio_topic: str) -> str:
    return audio_topic + PCM_SUFFIX


class Derived:
    """``feed(topic, msgtype, cdr)`` for each recorded message returns the derived (topic, type, cdr)
    messages to write beside it (usually none)."""

    def __init__(self, *, namespace: str = "") -> None:
        self.store = typestore()
        self._types = self.store.types
        self.odom, self.pose = absolute(topics.ODOM, namespace), absolute(topics.AGENT_POSE, namespace)
        self.audio = {absolute(topics.AUDIO, namespace): "samples",
                      absolute(topics.SEPARATED_AUDIO, namespace): "samples",
                      topics.GROUND_TRUTH: "target_monaural"}
        self.static_sent = False

    def topics(self) -> dict[str, str]:
        """Every topic this may write, with its type."""
        return {TF: TF_MESSAGE, TF_STATIC: TF_MESSAGE, **{pcm_topic(a): RAW_AUDIO for a in self.audio}}

    def feed(self, topic: str, msgtype: str, data: bytes | memoryview) -> list[tuple[str, str, bytes]]:
        if topic == self.odom and msgtype == "nav_msgs/msg/Odometry":
            msg = self.store.deserialize_cdr(data, msgtype)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            pose = (p.x, p.y, quaternion_yaw(q.x, q.y, q.z, q.w))
            return [self._tf(TF, [base_transform(pose)], msg.header.stamp)]
        if topic == self.pose and msgtype == "m2h_msgs/msg/AgentPose" and not self.static_sent:
            msg = self.store.deserialize_cdr(data, msgtype)
            self.static_sent = True
            # The simulator puts the ears at the pose's height and its camera at the ears.
            height = float(msg.pose.position.z)
            return [self._tf(TF_STATIC, static_transforms(head_height=height, eye_height=height), msg.header.stamp)]
        field = self.audio.get(topic)
        if field is not None and msgtype in ("m2h_msgs/msg/BinauralAudio", "m2h_msgs/msg/GroundTruth"):
            msg = self.store.deserialize_cdr(data, msgtype)
            samples = np.asarray(getattr(msg, field), np.float32)
            channels = int(msg.channels) if field == "samples" else 1
            if channels < 1 or samples.size % channels:
                return []
            audio = self._types[RAW_AUDIO](timestamp=msg.header.stamp,
                                           data=np.frombuffer(pcm_int16(samples.reshape(channels, -1), gain=PCM_GAIN), np.uint8),
                                           format="pcm-s16", sample_rate=int(msg.sample_rate),
                                           number_of_channels=channels)
            return [(pcm_topic(topic), RAW_AUDIO, bytes(self.store.serialize_cdr(audio, RAW_AUDIO)))]
        return []

    def _tf(self, topic: str, transforms: Iterable[Transform], stamp) -> tuple[str, str, bytes]:
        t = self._types
        stamped = [t["geometry_msgs/msg/TransformStamped"](
            header=t["std_msgs/msg/Header"](stamp=stamp, frame_id=tr.parent), child_frame_id=tr.child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](*tr.translation),
                rotation=t["geometry_msgs/msg/Quaternion"](*tr.rotation)))
            for tr in transforms]
        message = t[TF_MESSAGE](transforms=stamped)
        return topic, TF_MESSAGE, bytes(self.store.serialize_cdr(message, TF_MESSAGE))
