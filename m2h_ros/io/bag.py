"""rosbag2 bags (metadata.yaml + .mcap) written and read with rosbags: no ROS needed."""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.interfaces import Qos
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.typesys.store import Typestore

from m2h_ros.errors import BagError
from m2h_ros.io.msg_defs import typestore as m2h_typestore


@dataclass(frozen=True)
class BagMessage:
    topic: str
    msgtype: str
    timestamp: int  # ns, receive time
    message: Any  # a rosbags message object (dataclass-like, fields as in the .msg)


class BagWriter:
    """Writes a rosbag2 MCAP bag. Use as a context manager: metadata.yaml is written on close.

    rosbags keeps the open MCAP chunk (up to 1 MiB) in memory, so a writer killed with SIGKILL loses it.
    With ``flush_period_s`` the open chunk is closed and written to the file once it is that old (checked
    at each write; call :meth:`flush` from a timer to cover idle stretches too): a killed recorder then
    loses at most about that much, and the bag's complete chunks stay readable
    (:class:`~m2h_ros.io.mcap_stream.BagStream`)."""

    def __init__(self, path: str | Path, *, typestore: Typestore | None = None, overwrite: bool = False,
                 flush_period_s: float | None = None):
        if flush_period_s is not None and not flush_period_s > 0:
            raise BagError(f"flush_period_s must be > 0 (or None), got {flush_period_s!r}")
        self.path = Path(path)
        self.flush_period_s = flush_period_s
        self._chunk_opened: float | None = None  # monotonic time of the open chunk's first message
        if self.path.exists():
            if not overwrite:
                raise BagError(f"bag {self.path} already exists (pass overwrite=True to replace it)")
            shutil.rmtree(self.path)
        self._typestore = typestore or m2h_typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._connections: dict[str, Any] = {}
        try:
            self._writer.open()
        except WriterError as exc:
            raise BagError(f"cannot create bag {self.path}: {exc}") from exc

    def add_topic(self, topic: str, msgtype: str, *, offered_qos: Sequence[Qos] = ()) -> None:
        """Declare a topic before its first message, with the QoS its publishers offer (rosbag2 lists
        them in metadata.yaml and the MCAP channel, and ``ros2 bag play`` republishes with them)."""
        if topic in self._connections:
            raise BagError(f"topic {topic} is already in the bag")
        if msgtype not in self._typestore.types:
            raise BagError(f"unknown message type {msgtype!r} for topic {topic}")
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._typestore, offered_qos_profiles=list(offered_qos))

    def _connection(self, topic: str, msgtype: str):
        conn = self._connections.get(topic)
        if conn is None:
            self.add_topic(topic, msgtype)
            conn = self._connections[topic]
        elif conn.msgtype != msgtype:
            raise BagError(f"topic {topic} was recorded as {conn.msgtype}, now offered as {msgtype}")
        return conn

    def write_raw(self, topic: str, msgtype: str, timestamp: int, data: bytes | memoryview) -> None:
        """Write serialized CDR bytes as received from a raw subscription."""
        self._writer.write(self._connection(topic, msgtype), timestamp, data)
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
        storage = self._writer.storage  # rosbags' MCAP storage writer; None once closed
        if storage is None:
            return
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()
        self._chunk_opened = None

    def close(self) -> None:
        self._writer.close()

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
            for conn, timestamp, data in reader.messages(connections=conns):
                try:
                    message = store.deserialize_cdr(data, conn.msgtype)
                except Exception as exc:  # rosbags raises several types for garbled CDR
                    raise BagError(f"{path}: cannot decode a {conn.msgtype} on {conn.topic}: {exc}") from exc
                yield BagMessage(conn.topic, conn.msgtype, timestamp, message)
    except ReaderError as exc:
        raise BagError(f"{path} is not a readable rosbag2 bag: {exc}") from exc
