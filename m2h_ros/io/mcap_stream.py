"""Streaming read of rosbag2 MCAP bags, including damaged ones: raw messages in file order, one chunk
in memory at a time.

rosbags' reader needs ``metadata.yaml`` and the MCAP summary; a recorder killed with SIGKILL (ours or
``ros2 bag record``) leaves neither. This reader walks the data section record by record, so it
reads every complete chunk of such a bag and stops at the first incomplete record. What it finds
wrong is collected in :attr:`BagStream.problems` (each a :class:`BagError` naming the file, byte offset
and what is lost) and reading goes on where the framing allows: a chunk whose CRC or compression is
bad is skipped (named by its number, byte range and the topics its message indexes list; a closed file's
summary still declares the topics it held), an unknown type is reported per topic. Only errors that leave nothing to read (no
such path, not MCAP, not the ``ros2`` profile, a storage other than MCAP) raise.

Message definitions are checked against this checkout's ``m2h_msgs`` (and Jazzy's standard types) by
type hash, computed from the schema text in the file (else taken from ``metadata.yaml``).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import BinaryIO

import yaml
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
# zlib-ng's CRC-32 (carry-less multiply) runs several times faster than the system zlib's, which was an
# eighth of a replay step's CPU; the same checksum.
from zlib_ng.zlib_ng import crc32

from m2h_ros.errors import BagError
from m2h_ros.io.msg_defs import typestore as m2h_typestore

MAGIC = b"\x89MCAP0\r\n"
PROFILE = "ros2"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX, OP_DATA_END = (
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x0F)
KNOWN_OPS = frozenset(range(0x01, 0x10))  # 0x10..0x7F are reserved: seeing one means corrupt bytes
RECORD_HEAD = struct.Struct("<BQ")
MESSAGE_HEAD = struct.Struct("<HIQQ")
INDEX_HEAD = struct.Struct("<HI")  # message index: channel id, bytes of (log time, offset) pairs
CHUNK_HEAD = struct.Struct("<QQQI")
FOOTER = struct.Struct("<QQI")  # summary start, summary offset start, summary CRC


@dataclass(frozen=True)
class RawMessage:
    topic: str
    msgtype: str
    log_time: int  # ns: receive time
    data: memoryview  # CDR bytes: a view into its chunk (keeps the chunk alive while held)


@dataclass(frozen=True)
class ChannelInfo:
    topic: str
    msgtype: str
    encoding: str
    type_hash: str  # RIHS01 of the definition in the bag ("" if it could not be parsed)
    known: bool  # the type hash equals this checkout's definition of msgtype


@dataclass
class StreamStats:
    files: int = 0
    bytes: int = 0  # bytes of the MCAP files walked
    chunks: int = 0  # complete chunks read
    messages: int = 0
    complete: bool = False  # every file ended with a data-end record or footer


def _natural_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


@lru_cache(maxsize=256)
def definition_hash(name: str, text: str) -> str:
    """RIHS01 hash of a ros2msg schema (a .msg with its dependencies after ``MSG:`` separators)."""
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, name))
    return store.hash_rihs01(name)


@lru_cache(maxsize=256)
def _own_definition(name: str) -> str:
    """The ros2msg text this checkout writes for ``name`` (what our recorder puts in a bag)."""
    return m2h_typestore().generate_msgdef(name, ros_version=2)[0]


def _string(buf: memoryview, offset: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", buf, offset)
    end = offset + 4 + size
    if end > len(buf):
        raise ValueError("string runs past its record")
    return bytes(buf[offset + 4:end]).decode(), end


def _metadata_map(buf: memoryview, offset: int) -> dict[str, str]:
    (size,) = struct.unpack_from("<I", buf, offset)
    offset += 4
    end = offset + size
    values = {}
    while offset < end:
        key, offset = _string(buf, offset)
        values[key], offset = _string(buf, offset)
    return values


def _decompress(data: memoryview, compression: str, size: int) -> bytes | memoryview:
    if compression == "":
        return data  # a view into the chunk record, which its messages' views keep alive: no copy
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(bytes(data))
    raise ValueError(f"unsupported chunk compression {compression!r}")


@dataclass
class _Schema:
    name: str
    encoding: str
    text: str


@dataclass
class _FileState:
    path: Path
    schemas: dict[int, _Schema] = field(default_factory=dict)
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    undeclared: dict[int, int] = field(default_factory=dict)  # channel id -> messages skipped
    chunks: int = 0  # chunk records met so far
    damaged: _DamagedChunk | None = None  # the last chunk skipped, until its message indexes are read


@dataclass
class _DamagedChunk:
    """A skipped chunk, named once the message index records after it tell which topics it held."""
    number: int  # 1-based, in file order
    start: int  # byte range of the chunk record
    end: int
    log_times: tuple[int, int]  # first and last message's receive time (ns), from its header
    why: str
    lost: dict[int, int] = field(default_factory=dict)  # channel id -> messages


class BagStream:
    """The raw messages of a rosbag2 MCAP bag (a bag directory or one ``.mcap`` file), streamed.

    ``for message in BagStream(path).messages(): ...``; afterwards ``problems`` lists what was wrong
    and ``stats`` what was read. ``topics`` limits which messages are yielded (the rest are skipped
    without copying)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.problems: list[BagError] = []
        self.stats = StreamStats()
        self.channels: dict[str, ChannelInfo] = {}  # topic -> what the bag declares
        self.metadata: dict | None = None
        self._listed_hashes: dict[str, str] = {}
        self.files = self._files()

    def _problem(self, text: str) -> None:
        self.problems.append(BagError(text))

    def _files(self) -> list[Path]:
        if not self.path.exists():
            raise BagError(f"bag {self.path} does not exist")
        if self.path.is_file():
            return [self.path]
        meta_path = self.path / "metadata.yaml"
        if meta_path.is_file():
            try:
                info = yaml.safe_load(meta_path.read_text())["rosbag2_bagfile_information"]
                storage = info.get("storage_identifier", "")
                names = list(info.get("relative_file_paths") or [])
                for entry in info.get("topics_with_message_count") or []:
                    topic = entry["topic_metadata"]
                    if topic.get("type_description_hash"):
                        self._listed_hashes[topic["name"]] = topic["type_description_hash"]
            except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError) as exc:
                self._problem(f"{meta_path}: not a rosbag2 metadata file ({exc}); reading the .mcap files")
            else:
                self.metadata = info
                if storage != "mcap":
                    raise BagError(f"{self.path}: storage {storage!r} is not read here; record with "
                                   f"`ros2 bag record -s mcap`")
                files = [self.path / name for name in names]
                missing = [f.name for f in files if not f.is_file()]
                if missing:
                    self._problem(f"{self.path}: metadata.yaml lists missing file(s) {missing}")
                files = [f for f in files if f.is_file()]
                if files:
                    return files
        else:
            self._problem(f"{self.path}: no metadata.yaml: the recorder did not close the bag (killed?); "
                          f"reading the .mcap files up to their last complete chunk")
        files = sorted(self.path.glob("*.mcap"), key=_natural_key)
        if not files:
            raise BagError(f"{self.path}: no .mcap file in the bag directory")
        return files

    def messages(self, *, topics: set[str] | None = None) -> Iterator[RawMessage]:
        ends = [False] * len(self.files)
        for k, path in enumerate(self.files):
            ends[k] = yield from self._read_file(path, topics)
        self.stats.complete = all(ends)
        listed = self.metadata and self.metadata.get("message_count")
        if listed and self.stats.messages < listed:
            self._problem(f"{self.path}: read {self.stats.messages} of the {listed} messages metadata.yaml lists")

    def _read_file(self, path: Path, topics: set[str] | None) -> Generator[RawMessage, None, bool]:
        """Yields the file's messages; returns whether it ended with a data-end record or footer."""
        state = _FileState(path)
        closed = False
        size = path.stat().st_size
        self.stats.files += 1
        with path.open("rb") as stream:
            self._check_start(stream, path)
            data_start = stream.tell()
            self._summary_declarations(state, stream, size)
            stream.seek(data_start)
            while True:
                offset = stream.tell()
                head = stream.read(RECORD_HEAD.size)
                if not head:
                    self._problem(f"{path}: ended without an MCAP data-end record or footer at byte {offset} "
                                  f"(the writer did not close it); kept {self.stats.chunks} complete chunk(s)")
                    break
                if len(head) < RECORD_HEAD.size:
                    self._problem(f"{path}: truncated at byte {offset}: {len(head)} byte(s) of a record header; "
                                  f"kept everything before it")
                    break
                op, length = RECORD_HEAD.unpack(head)
                if state.damaged is not None and op != OP_MESSAGE_INDEX:
                    self._report_damage(state)
                if op not in KNOWN_OPS and op < 0x80:
                    self._problem(f"{path}: corrupt at byte {offset}: opcode 0x{op:02x} is not an MCAP "
                                  f"record; nothing after it can be read")
                    break
                if op in (OP_DATA_END, OP_FOOTER):
                    closed = True
                    break
                if length > size - stream.tell():
                    what = "chunk" if op == OP_CHUNK else f"record 0x{op:02x}"
                    self._problem(f"{path}: truncated at byte {offset}: a {what} of {length} bytes with "
                                  f"{size - stream.tell()} left (lost from there on)")
                    break
                if op == OP_MESSAGE_INDEX and state.damaged is not None:
                    self._count_lost(state, stream.read(length))
                    continue
                if op not in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK):
                    stream.seek(length, 1)  # indexes, attachments, metadata: not needed to stream
                    continue
                body = memoryview(stream.read(length))
                if op == OP_CHUNK:
                    yield from self._chunk(state, body, offset, offset + RECORD_HEAD.size + length, topics)
                    continue
                try:
                    message = self._record(state, op, body, topics)
                except (struct.error, ValueError, UnicodeDecodeError) as exc:
                    self._problem(f"{path}: corrupt record 0x{op:02x} at byte {offset} skipped ({exc})")
                    continue
                if message is not None:
                    yield message
        if state.damaged is not None:
            self._report_damage(state)
        self.stats.bytes += size
        for channel_id, count in state.undeclared.items():
            self._problem(f"{path}: {count} message(s) on channel {channel_id}, whose declaration was lost, skipped")
        return closed

    def _summary_declarations(self, state: _FileState, stream: BinaryIO, size: int) -> None:
        """Registers the schemas and channels a closed file's summary section repeats, so messages whose
        declaration sat in a damaged chunk still decode. A file without a readable footer (a killed
        writer) has none: its data section's declarations are all there is."""
        tail_size = RECORD_HEAD.size + FOOTER.size + len(MAGIC)
        if size < len(MAGIC) + tail_size:
            return
        stream.seek(size - tail_size)
        tail = stream.read(tail_size)
        if tail[-len(MAGIC):] != MAGIC or tail[0] != OP_FOOTER:
            return
        summary_start, offsets_start, _ = FOOTER.unpack_from(tail, RECORD_HEAD.size)
        end = offsets_start or size - tail_size
        if not 0 < summary_start < end <= size:
            return
        stream.seek(summary_start)
        summary = memoryview(stream.read(end - summary_start))
        pos = 0
        try:
            while pos + RECORD_HEAD.size <= len(summary):
                op, length = RECORD_HEAD.unpack_from(summary, pos)
                pos += RECORD_HEAD.size
                if op in (OP_SCHEMA, OP_CHANNEL):
                    self._record(state, op, summary[pos:pos + length], None)
                pos += length
        except (struct.error, ValueError, UnicodeDecodeError):
            pass  # a damaged summary: the data section's own declarations remain

    def _check_start(self, stream: BinaryIO, path: Path) -> None:
        if stream.read(len(MAGIC)) != MAGIC:
            raise BagError(f"{path} is not an MCAP file (no MCAP magic at its start)")
        head = stream.read(RECORD_HEAD.size)
        if len(head) < RECORD_HEAD.size or RECORD_HEAD.unpack(head)[0] != OP_HEADER:
            raise BagError(f"{path}: MCAP header record missing")
        body = memoryview(stream.read(RECORD_HEAD.unpack(head)[1]))
        try:
            profile, _ = _string(body, 0)
        except (struct.error, ValueError, UnicodeDecodeError) as exc:
            raise BagError(f"{path}: unreadable MCAP header ({exc})") from exc
        if profile != PROFILE:
            raise BagError(f"{path} is a foreign MCAP file: profile {profile!r}, not {PROFILE!r} (rosbag2)")

    def _chunk(self, state: _FileState, body: memoryview, offset: int, end: int, topics) -> Iterator[RawMessage]:
        state.chunks += 1
        log_times = (0, 0)
        try:
            start_time, end_time, uncompressed_size, crc = CHUNK_HEAD.unpack_from(body, 0)
            log_times = (start_time, end_time)
            compression, pos = _string(body, CHUNK_HEAD.size)
            (records_size,) = struct.unpack_from("<Q", body, pos)
            pos += 8
            if pos + records_size > len(body):
                raise ValueError("records run past the chunk")
            data = _decompress(body[pos:pos + records_size], compression, uncompressed_size)
            if len(data) != uncompressed_size:
                raise ValueError(f"{len(data)} bytes decompressed, {uncompressed_size} declared")
            if crc and (computed := crc32(data)) != crc:
                raise ValueError(f"CRC-32 mismatch: the chunk says {crc:08x}, its bytes give {computed:08x}")
        except Exception as exc:  # zstd, lz4 and struct raise their own types for garbled data
            # Named once the message indexes after it are read: they tell which topics are lost.
            state.damaged = _DamagedChunk(state.chunks, offset, end, log_times, str(exc))
            return
        records = memoryview(data)
        pos = 0
        chunk_messages = []
        counted = self.stats.messages
        try:
            while pos < len(records):
                op, length = RECORD_HEAD.unpack_from(records, pos)
                pos += RECORD_HEAD.size
                if pos + length > len(records):
                    raise ValueError(f"record 0x{op:02x} runs past the chunk")
                message = self._record(state, op, records[pos:pos + length], topics)
                if message is not None:
                    chunk_messages.append(message)
                pos += length
        except (struct.error, ValueError, UnicodeDecodeError) as exc:
            self._problem(f"{state.path}: corrupt records in the chunk at byte {offset} skipped ({exc})")
            self.stats.messages = counted
            return
        self.stats.chunks += 1
        yield from chunk_messages  # a chunk counts only once it parsed completely

    def _count_lost(self, state: _FileState, body: bytes) -> None:
        try:
            channel_id, size = INDEX_HEAD.unpack_from(body, 0)
        except struct.error:
            return
        state.damaged.lost[channel_id] = state.damaged.lost.get(channel_id, 0) + size // 16

    def _report_damage(self, state: _FileState) -> None:
        damaged, state.damaged = state.damaged, None
        lost = ", ".join(f"{state.channels[c].topic if c in state.channels else f'channel {c}'} ({n})"
                         for c, n in sorted(damaged.lost.items(), key=lambda item: str(state.channels.get(item[0]))))
        first, last = (t / 1e9 for t in damaged.log_times)
        self._problem(f"{state.path}: corrupt chunk {damaged.number} (bytes {damaged.start}-{damaged.end}, "
                      f"receive times {first:.3f}-{last:.3f} s) skipped, never decoded ({damaged.why}); "
                      f"lost messages: {lost or 'unknown (no message index after it)'}")

    def _record(self, state: _FileState, op: int, body: memoryview, topics) -> RawMessage | None:
        """Registers a schema or channel, or returns a message (None if filtered out)."""
        if op == OP_MESSAGE:
            channel_id, _, log_time, _ = MESSAGE_HEAD.unpack_from(body, 0)
            channel = state.channels.get(channel_id)
            if channel is None:  # its channel record was in a lost or corrupt chunk
                state.undeclared[channel_id] = state.undeclared.get(channel_id, 0) + 1
                return None
            self.stats.messages += 1
            if topics is None or channel.topic in topics:
                return RawMessage(channel.topic, channel.msgtype, log_time, body[MESSAGE_HEAD.size:])
        elif op == OP_SCHEMA:
            (schema_id,) = struct.unpack_from("<H", body, 0)
            name, pos = _string(body, 2)
            encoding, pos = _string(body, pos)
            (size,) = struct.unpack_from("<I", body, pos)
            text = bytes(body[pos + 4:pos + 4 + size]).decode()
            state.schemas[schema_id] = _Schema(name, encoding, text)
        elif op == OP_CHANNEL:
            channel_id, schema_id = struct.unpack_from("<HH", body, 0)
            topic, pos = _string(body, 4)
            encoding, pos = _string(body, pos)
            metadata = _metadata_map(body, pos)
            if channel_id not in state.channels:
                state.channels[channel_id] = self._channel(state, topic, encoding, schema_id, metadata)
        return None

    def _channel(self, state: _FileState, topic: str, encoding: str, schema_id: int,
                 metadata: dict[str, str]) -> ChannelInfo:
        schema = state.schemas.get(schema_id)
        if schema is None:
            self._problem(f"{state.path}: topic {topic} has no message definition in the bag; not decoded")
            return ChannelInfo(topic, "", encoding, "", False)
        # The schema text is what the data was written with; a listed hash only stands in for it.
        type_hash = ""
        ours = m2h_typestore()
        if schema.encoding == "ros2msg" and schema.name in ours.types and schema.text == _own_definition(schema.name):
            type_hash = ours.hash_rihs01(schema.name)  # the text this checkout writes: no need to parse it
        elif schema.encoding == "ros2msg":
            try:
                type_hash = definition_hash(schema.name, schema.text)
            except Exception as exc:  # rosbags' parser raises its own types for bad .msg text
                self._problem(f"{state.path}: topic {topic}: cannot parse the definition of {schema.name} ({exc})")
        type_hash = type_hash or self._listed_hashes.get(topic) or metadata.get("topic_type_hash", "")
        known = encoding == "cdr" and schema.name in ours.types and type_hash == ours.hash_rihs01(schema.name)
        if schema.name in ours.types and not known:
            self._problem(f"{state.path}: topic {topic}: {schema.name} in the bag is not this checkout's "
                          f"definition (hash {type_hash or '?'} vs {ours.hash_rihs01(schema.name)}, "
                          f"encoding {encoding!r}); not decoded")
        info = ChannelInfo(topic, schema.name, encoding, type_hash, known)
        previous = self.channels.setdefault(topic, info)
        if previous.msgtype != info.msgtype:
            self._problem(f"{state.path}: topic {topic} carries both {previous.msgtype} and {info.msgtype}")
        return info
