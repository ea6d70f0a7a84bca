"""rosbag2 bags (metadata.yaml + .mcap) written with the `mcap` package and read with rosbags: no ROS
needed.

The files follow what rosbag2 Jazzy's MCAP storage plugin (rosbag2_storage_mcap) writes: profile ``ros2``,
one ``ros2msg`` schema per type, ``cdr`` channels whose metadata holds ``offered_qos_profiles`` (the YAML
rosbag2 serializes) and ``topic_type_hash`` (RIHS01), a ``rosbag2`` metadata record and ``metadata.yaml``
version 9 with ``ros_distro`` from the environment. One addition: every chunk carries its CRC-32 (rosbag2
Jazzy leaves it 0 unless configured), so a damaged chunk is found on every read, never decoded as data.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from mcap.writer import CompressionType, Writer
from rosbags.interfaces import Qos
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys.store import Typestore

from m2h_ros.errors import BagError
from m2h_ros.io.msg_defs import ensure_known, typestore as m2h_typestore

METADATA_VERSION = 9  # rosbag2 Jazzy's metadata.yaml version
CHUNK_SIZE = 1 << 20  # bytes of records per chunk, as rosbags and rosbag2 (mcap's default)
# Of each MCAP chunk (m2h_ros.io.topic_selection.COMPRESSIONS, the recorder's choices, names these)
COMPRESSION_TYPES = {"none": CompressionType.NONE, "zstd": CompressionType.ZSTD}
LIBRARY = "m2h_ros"


def ros_distro() -> str:
    """The distro the bag says it was recorded with: ROS_DISTRO, else jazzy (the wheels' distro)."""
    return os.environ.get("ROS_DISTRO") or "jazzy"


def qos_yaml(profiles: Sequence[Qos]) -> str:
    """QoS profiles as rosbag2 Jazzy serializes them into an MCAP channel (yaml-cpp's block style)."""
    if not profiles:
        return "[]"
    return yaml.safe_dump(dump_qos_v9(list(profiles)), sort_keys=False, default_flow_style=False).rstrip("\n")


@dataclass(frozen=True)
class BagMessage:
    topic: str
    msgtype: str
    timestamp: int  # ns, receive time
    message: Any  # a rosbags message object (dataclass-like, fields as in the .msg)


@dataclass
class _Topic:
    msgtype: str
    channel_id: int
    type_hash: str
    offered_qos: list[Qos]
    count: int = 0


class BagWriter:
    """Writes a rosbag2 MCAP bag. Use as a context manager: metadata.yaml is written on close.

    The open MCAP chunk (up to 1 MiB) is held in memory, so a writer killed with SIGKILL loses it. With
    ``flush_period_s`` the open chunk is closed and written to the file once it is that old (checked at
    each write; call :meth:`flush` from a timer to cover idle stretches too): a killed recorder then loses
    at most about that much, and the bag's complete chunks stay readable
    (:class:`~m2h_ros.io.mcap_stream.BagStream`)."""

    def __init__(self, path: str | Path, *, typestore: Typestore | None = None, overwrite: bool = False,
                 flush_period_s: float | None = None, compression: str = "none"):
        if flush_period_s is not None and not flush_period_s > 0:
            raise BagError(f"flush_period_s must be > 0 (or None), got {flush_period_s!r}")
        if compression not in COMPRESSION_TYPES:
            raise BagError(f"compression must be one of {', '.join(COMPRESSION_TYPES)}, got {compression!r}")
        self.path = Path(path)
        self.flush_period_s = flush_period_s
        self._chunk_opened: float | None = None  # monotonic time of the open chunk's first message
        if self.path.exists():
            if not overwrite:
                raise BagError(f"bag {self.path} already exists (pass overwrite=True to replace it)")
            shutil.rmtree(self.path)
        self._typestore = typestore or m2h_typestore()
        self._file = self.path / f"{self.path.name}_0.mcap"
        try:
            self.path.mkdir(parents=True)
            self._stream = self._file.open("xb")
        except OSError as exc:
            raise BagError(f"cannot create bag {self.path}: {exc}") from exc
        self._writer = Writer(self._stream, chunk_size=CHUNK_SIZE, compression=COMPRESSION_TYPES[compression],
                              enable_crcs=True)
        self._writer.start(profile="ros2", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self._first = self._last = None  # receive times (ns) of the earliest and latest message
        self._closed = False

    def add_topic(self, topic: str, msgtype: str, *, offered_qos: Sequence[Qos] = ()) -> None:
        """Declare a topic before its first message, with the QoS its publishers offer (rosbag2 lists
        them in metadata.yaml and the MCAP channel, and ``ros2 bag play`` republishes with them)."""
        if topic in self._topics:
            raise BagError(f"topic {topic} is already in the bag")
        try:
            ensure_known(self._typestore, msgtype)
        except BagError as exc:
            raise BagError(f"topic {topic}: {exc}") from None
        type_hash = self._typestore.hash_rihs01(msgtype)
        if msgtype not in self._schemas:
            text, _ = self._typestore.generate_msgdef(msgtype, ros_version=2)
            self._schemas[msgtype] = self._writer.register_schema(msgtype, "ros2msg", text.encode())
        # The two keys, in this order, are what rosbag2_storage_mcap (jazzy) puts in a channel's metadata.
        channel_id = self._writer.register_channel(
            topic, "cdr", self._schemas[msgtype],
            {"offered_qos_profiles": qos_yaml(offered_qos), "topic_type_hash": type_hash})
        self._topics[topic] = _Topic(msgtype, channel_id, type_hash, list(offered_qos))

    def type_hash(self, topic: str) -> str:
        """The RIHS01 hash of the definition ``topic`` is recorded with (its MCAP schema)."""
        return self._topics[topic].type_hash

    def write_raw(self, topic: str, msgtype: str, timestamp: int, data: bytes | memoryview) -> None:
        """Write serialized CDR bytes as received from a raw subscription."""
        entry = self._topics.get(topic)
        if entry is None:
            self.add_topic(topic, msgtype)
            entry = self._topics[topic]
        elif entry.msgtype != msgtype:
            raise BagError(f"topic {topic} was recorded as {entry.msgtype}, now offered as {msgtype}")
        self._writer.add_message(entry.channel_id, log_time=timestamp, data=data, publish_time=timestamp)
        entry.count += 1
        if self._first is None:
            self._first = self._last = timestamp
        else:
            self._first, self._last = min(self._first, timestamp), max(self._last, timestamp)
        if self.flush_period_s is not None:
            now = time.monotonic()
            if self._chunk_opened is None:
                self._chunk_opened = now
            elif now - self._chunk_opened >= self.flush_period_s:
                self.flush()

    def write(self, topic: str, msgtype: str, timestamp: int, message: Any) -> None:
        """Serialize a rosbags message object and write it."""
        self.write_raw(topic, msgtype, timestamp, self._typestore.serialize_cdr(message, msgtype))

    def flush(self) -> None:
        """Close the open chunk (if it holds messages) and hand everything written to the OS."""
        if self._closed:
            return
        self._writer.flush()
        self._chunk_opened = None

    def metadata(self) -> dict:
        """metadata.yaml's ``rosbag2_bagfile_information`` for what was written so far."""
        start = self._first or 0
        duration = (self._last - self._first) if self._first is not None else 0
        count = sum(t.count for t in self._topics.values())
        return {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": name, "type": t.msgtype, "serialization_format": "cdr",
                                    "offered_qos_profiles": dump_qos_v9(t.offered_qos),
                                    "type_description_hash": t.type_hash},
                 "message_count": t.count}
                for name, t in self._topics.items()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self._file.name],
            "files": [{"path": self._file.name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": count}],
            "custom_data": None,
            "ros_distro": ros_distro(),
        }

    def close(self) -> None:
        if self._closed:
            return
        info = self.metadata()
        self._writer.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(info, sort_keys=False)})
        self._writer.finish()
        self._stream.close()
        self._closed = True
        text = yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)
        tmp = self.path / "metadata.yaml.tmp"
        tmp.write_text(text)
        tmp.replace(self.path / "metadata.yaml")

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def read_messages(
    path: str | Path, *, topics: Iterable[str] | None = None, typestore: Typestore | None = None
) -> Iterator[BagMessage]:
    """Yield the deserialized messages of a bag in time order, optionally only some topics."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    store = typestore or m2h_typestore()
    try:
        with Reader(path) as reader:
            wanted = set(topics) if topics is not None else None
            conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
            if not conns:  # rosbags reads every connection when given none
                return
            for conn, timestamp, data in reader.messages(connections=conns):
                try:
                    message = store.deserialize_cdr(data, conn.msgtype)
                except Exception as exc:  # rosbags raises several types for garbled CDR
                    raise BagError(f"{path}: cannot decode a {conn.msgtype} on {conn.topic}: {exc}") from exc
                yield BagMessage(conn.topic, conn.msgtype, timestamp, message)
    except ReaderError as exc:
        raise BagError(f"{path} is not a readable rosbag2 bag: {exc}") from exc
