"""Topics derived from the raw ones, for tools that expect standard types and for people watching: the
robot's TF tree (tf2_msgs/TFMessage on /tf and /tf_static, from the odometry and the agent's pose), audio
to listen to (foxglove_msgs/RawAudio, pcm-s16, from the mixture, the separated estimate and the target)
and, with ``views``, the spectrogram pictures (sensor_msgs/Image, from the mixture, the separator's
spectrograms and the target) and the robot's path (visualization_msgs/MarkerArray, from its poses).

ROS-free: it works on serialized CDR, so the recorder can write it where neither tf2_msgs nor
foxglove_msgs is installed (the bag writer knows their released definitions, see io/msg_defs.py), a
live view can serve it the same way, and ``m2h-derive`` adds every one of them to a bag recorded
without them (io/derive_bag.py). The nodes publish the pictures and the path with the same builders
(:func:`spectrogram_image_cdr`, :func:`path_markers_cdr`), so a derived one equals, byte for byte, what
the node would have sent. Where the graph publishes a topic itself, a recording keeps that one.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable

import numpy as np
from rosbags.interfaces import Nodetype, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from m2h_ros import topics
from m2h_ros.core.audio.display import BINS_PER_ROW, spectrogram_image
from m2h_ros.core.audio.pcm import pcm_int16
from m2h_ros.core.audio.stft import StftConfig, stft
from m2h_ros.core.world.frames import HEAD, MAP, Transform, base_transform, quaternion_yaw, static_transforms
from m2h_ros.io.msg_defs import RAW_AUDIO, TF_MESSAGE, typestore

TF, TF_STATIC = topics.TF, topics.TF_STATIC
IMAGE, MARKERS = "sensor_msgs/msg/Image", "visualization_msgs/msg/MarkerArray"
PCM_SUFFIX = "/pcm"  # RawAudio of an audio topic: the same name with this suffix
# Float audio to pcm-s16, in bags and in the live view alike (mixtures peak near 20; full scale is 25).
PCM_GAIN = 0.04
_INFINITE = QosTime(9223372036, 854775807)  # rmw's "infinite" duration, as a publisher's QoS reports it
# The path's look (visualization_msgs/Marker LINE_STRIP and SPHERE_LIST in the map frame)
PATH_COLOUR, PATH_WIDTH, PATH_DOT = (0.1, 0.4, 0.9, 1.0), 0.05, 0.15
LINE_STRIP, SPHERE_LIST, ADD = 4, 7, 0


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


def derived_topics(namespace: str = "") -> dict[str, str]:
    """Every topic a bag can have derived from its raw topics (``Derived(views=True)``), with its type:
    what a recorder that does not keep derived products leaves out."""
    return Derived(namespace=namespace, views=True).topics()


@functools.cache
def _default_fields(msgtype: str) -> dict[str, object]:
    """Every field of ``msgtype`` zero, empty or default-built (rosbags' classes take every field), built
    once: the values are shared between messages, so none may be changed in place."""
    store = typestore()
    _, fields = store.fielddefs[msgtype]

    def value(desc):
        kind, detail = desc
        if kind == Nodetype.NAME:
            return store.types[detail](**_default_fields(detail))
        if kind == Nodetype.BASE:
            return "" if detail[0] == "string" else False if detail[0] == "bool" else 0
        element = detail[0]
        if element[0] == Nodetype.BASE and element[1][0] != "string":
            return np.zeros(detail[1] if kind == Nodetype.ARRAY else 0, np.dtype(_NUMPY[element[1][0]]))
        return [value(element) for _ in range(detail[1] if kind == Nodetype.ARRAY else 0)]

    return {name: value(desc) for name, desc in fields}


def _message(msgtype: str, **fields):
    """A ``msgtype`` with ``fields`` set and every other field at its default."""
    return typestore().types[msgtype](**{**_default_fields(msgtype), **fields})


_NUMPY = {"bool": "bool", "byte": "uint8", "char": "uint8", "int8": "int8", "uint8": "uint8", "int16": "int16",
          "uint16": "uint16", "int32": "int32", "uint32": "uint32", "int64": "int64", "uint64": "uint64",
          "float32": "float32", "float64": "float64"}


def _stamp(stamp_ns: int):
    return typestore().types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                             nanosec=stamp_ns % 1_000_000_000)


def _cdr(message, msgtype: str) -> bytes:
    return bytes(typestore().serialize_cdr(message, msgtype))


def spectrogram_image_cdr(magnitude: np.ndarray, *, stamp_ns: int) -> bytes:
    """A linear STFT magnitude, (F, T) or (channels, F, T), as the 32FC1 picture in dB an image panel
    shows (core.audio.display.spectrogram_image), in the head frame: a serialized sensor_msgs/Image."""
    return _picture_cdr(spectrogram_image(magnitude), stamp_ns=stamp_ns)


def _picture_cdr(picture: np.ndarray, *, stamp_ns: int) -> bytes:
    height, width = picture.shape
    t = typestore().types
    image = t[IMAGE](header=t["std_msgs/msg/Header"](stamp=_stamp(stamp_ns), frame_id=HEAD), height=height,
                     width=width, encoding="32FC1", is_bigendian=0, step=4 * width,
                     data=np.frombuffer(np.ascontiguousarray(picture, "<f4").tobytes(), np.uint8))
    return _cdr(image, IMAGE)


def path_markers_cdr(positions: np.ndarray, *, height: float, stamp_ns: int) -> bytes:
    """The robot's positions so far this episode, (K, 2) metres, as a line through them and a dot at each
    in the map frame: a serialized visualization_msgs/MarkerArray."""
    t = typestore().types
    points = [t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(height))
              for x, y in np.asarray(positions, float).reshape(-1, 2)]
    header = t["std_msgs/msg/Header"](stamp=_stamp(stamp_ns), frame_id=MAP)
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    colour = t["std_msgs/msg/ColorRGBA"](*(float(v) for v in PATH_COLOUR))
    markers = [_message("visualization_msgs/msg/Marker", header=header, ns="path", id=marker_id, type=kind,
                        action=ADD, pose=pose, scale=t["geometry_msgs/msg/Vector3"](*(float(v) for v in scale)),
                        color=colour, points=points)
               for marker_id, (kind, scale) in enumerate(((LINE_STRIP, (PATH_WIDTH, 0.0, 0.0)),
                                                          (SPHERE_LIST, (PATH_DOT,) * 3)))]
    return _cdr(t[MARKERS](markers=markers), MARKERS)


class Derived:
    """``feed(topic, msgtype, cdr)`` for each recorded message returns the derived (topic, type, cdr)
    messages to write beside it (usually none). ``views``: also the spectrogram pictures and the path."""

    def __init__(self, *, namespace: str = "", views: bool = False) -> None:
        self.store = typestore()
        self._types = self.store.types
        self.odom, self.pose = absolute(topics.ODOM, namespace), absolute(topics.AGENT_POSE, namespace)
        self.audio = {absolute(topics.AUDIO, namespace): "samples",
                      absolute(topics.SEPARATED_AUDIO, namespace): "samples",
                      topics.GROUND_TRUTH: "target_monaural"}
        self.static_sent = False
        # source topic -> picture topic: waveforms are shown through their STFT, spectrograms as they are
        self.pictures = {absolute(source, namespace): absolute(picture, namespace) for source, picture in (
            (topics.AUDIO, topics.MIXTURE_IMAGE), (topics.SEPARATED_BINAURAL, topics.BINAURAL_IMAGE),
            (topics.MONAURAL, topics.MONAURAL_IMAGE), (topics.REFINED, topics.REFINED_IMAGE),
            (topics.GROUND_TRUTH, topics.TARGET_IMAGE))} if views else {}
        self.path_topic = absolute(topics.PATH, namespace) if views else None
        self.path: tuple[str, list[tuple[float, float]]] = ("", [])  # episode id, its positions so far
        # source topic -> its last samples, their pcm-s16 bytes and picture: the target's dry clip is the
        # same at every step of an episode, and is converted once
        self._converted: dict[str, tuple[np.ndarray, bytes, np.ndarray | None]] = {}

    def topics(self) -> dict[str, str]:
        """Every topic this may write, with its type."""
        views = {**{picture: IMAGE for picture in self.pictures.values()},
                 **({self.path_topic: MARKERS} if self.path_topic else {})}
        return {TF: TF_MESSAGE, TF_STATIC: TF_MESSAGE, **{pcm_topic(a): RAW_AUDIO for a in self.audio}, **views}

    def sources(self) -> dict[str, str]:
        """Each topic of ``topics()`` with the topic it is made from."""
        made = {TF: self.odom, TF_STATIC: self.pose, **{pcm_topic(a): a for a in self.audio},
                **{picture: source for source, picture in self.pictures.items()}}
        return {**made, **({self.path_topic: self.pose} if self.path_topic else {})}

    def feed(self, topic: str, msgtype: str, data: bytes | memoryview) -> list[tuple[str, str, bytes]]:
        out = []
        if topic == self.odom and msgtype == "nav_msgs/msg/Odometry":
            msg = self.store.deserialize_cdr(data, msgtype)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            pose = (p.x, p.y, quaternion_yaw(q.x, q.y, q.z, q.w))
            return [self._tf(TF, [base_transform(pose)], msg.header.stamp)]
        if topic == self.pose and msgtype == "m2h_msgs/msg/AgentPose":
            msg = self.store.deserialize_cdr(data, msgtype)
            if not self.static_sent:
                self.static_sent = True
                # The simulator puts the ears at the pose's height and its camera at the ears.
                height = float(msg.pose.position.z)
                out.append(self._tf(TF_STATIC, static_transforms(head_height=height, eye_height=height),
                                    msg.header.stamp))
            if self.path_topic is not None:
                out.append(self._path(msg))
            return out
        field = self.audio.get(topic)
        picture = self.pictures.get(topic)
        if field is None and picture is None:
            return out
        if msgtype in ("m2h_msgs/msg/BinauralAudio", "m2h_msgs/msg/GroundTruth") and field is not None:
            msg = self.store.deserialize_cdr(data, msgtype)
            samples = np.asarray(getattr(msg, field), np.float32)
            channels = int(msg.channels) if field == "samples" else 1
            if channels < 1 or samples.size % channels:
                return out
            planar = samples.reshape(channels, -1)
            last = self._converted.get(topic)
            if last is not None and np.array_equal(last[0], planar):  # equal shapes and values
                _, pcm, image = last
            else:
                pcm, image = pcm_int16(planar, gain=PCM_GAIN), None
                if picture is not None and np.all(np.isfinite(planar)):
                    config = StftConfig(sample_rate=int(msg.sample_rate), clip_samples=planar.shape[-1])
                    image = spectrogram_image(np.abs(stft(planar[0] if field != "samples" else planar, config=config)))
                self._converted[topic] = (planar.copy(), pcm, image)  # the message's buffer may be reused
            audio = self._types[RAW_AUDIO](timestamp=msg.header.stamp, data=np.frombuffer(pcm, np.uint8),
                                           format="pcm-s16", sample_rate=int(msg.sample_rate),
                                           number_of_channels=channels)
            out.append((pcm_topic(topic), RAW_AUDIO, _cdr(audio, RAW_AUDIO)))
            if picture is not None and image is not None:
                out.append((picture, IMAGE, _picture_cdr(image, stamp_ns=_nanoseconds(msg.header.stamp))))
        elif msgtype == "m2h_msgs/msg/Spectrogram" and picture is not None:
            msg = self.store.deserialize_cdr(data, msgtype)
            values = np.asarray(msg.data, np.float32)
            shape = tuple(int(n) for n in msg.shape)
            if shape and values.size == np.prod(shape) and shape[-2] % BINS_PER_ROW == 0 and not msg.log_magnitude:
                out.append((picture, IMAGE, spectrogram_image_cdr(values.reshape(shape),
                                                                  stamp_ns=_nanoseconds(msg.header.stamp))))
        return out

    def _path(self, msg) -> tuple[str, str, bytes]:
        if msg.episode_id != self.path[0]:
            self.path = (msg.episode_id, [])
        positions = self.path[1]
        positions.append((float(msg.pose.position.x), float(msg.pose.position.y)))
        return self.path_topic, MARKERS, path_markers_cdr(np.array(positions), height=float(msg.pose.position.z),
                                                          stamp_ns=_nanoseconds(msg.header.stamp))

    def _tf(self, topic: str, transforms: Iterable[Transform], stamp) -> tuple[str, str, bytes]:
        t = self._types
        stamped = [t["geometry_msgs/msg/TransformStamped"](
            header=t["std_msgs/msg/Header"](stamp=stamp, frame_id=tr.parent), child_frame_id=tr.child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](*tr.translation),
                rotation=t["geometry_msgs/msg/Quaternion"](*tr.rotation)))
            for tr in transforms]
        message = t[TF_MESSAGE](transforms=stamped)
        return topic, TF_MESSAGE, _cdr(message, TF_MESSAGE)


def _nanoseconds(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
