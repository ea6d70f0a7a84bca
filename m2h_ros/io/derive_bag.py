"""Add to a recorded bag the topics derived from its raw ones (io/derived.py: spectrogram pictures, pcm-s16
tracks, the path, TF) that it lacks: what a recorder with ``keep_derived: false`` leaves out, so that
Foxglove, rviz and ``ros2 bag play`` see the same bag as one recorded with them.

Each derived message is written right after the message it comes from, with its receive time; every
message of the bag is kept as it was, with its topic's QoS. The bag is rewritten beside itself and swapped
in once complete (a failure leaves it as it was); a bag that already holds every derived topic it can
have is left untouched.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import make_reader
from rosbags.highlevel import AnyReader, AnyReaderError

from m2h_ros.errors import BagError
from m2h_ros.io.bag import BagWriter
from m2h_ros.io.derived import Derived, offered_qos
from m2h_ros.io.msg_defs import add_types, typestore


@dataclass
class DeriveResult:
    bag: Path  # the bag that now holds them
    added: dict[str, int] = field(default_factory=dict)  # derived topic -> messages written

    @property
    def summary(self) -> str:
        if not self.added:
            return f"{self.bag}: nothing to add (it holds every derived topic its raw topics give)"
        topics = ", ".join(f"{topic} {count}" for topic, count in self.added.items())
        return f"{self.bag}: added {sum(self.added.values())} derived messages ({topics})"


def _compression(bag: Path) -> str:
    """The compression of the bag's first chunk ("none" or "zstd"), which the rewrite keeps."""
    for path in sorted(bag.glob("*.mcap")) if bag.is_dir() else [bag]:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
        for index in summary.chunk_indexes if summary is not None else ():
            return "zstd" if index.compression == "zstd" else "none"
    return "none"


def _messages(reader: AnyReader, derived: Derived, present: set[str]) -> Iterator[tuple[str, str, int, bytes, bool]]:
    """(topic, type, receive time, CDR, derived?) of every message and, after it, its new derived ones."""
    for connection, timestamp, data in reader.messages():
        yield connection.topic, connection.msgtype, timestamp, data, False
        for topic, msgtype, extra in derived.feed(connection.topic, connection.msgtype, data):
            if topic not in present:
                yield topic, msgtype, timestamp, extra, True


def derive_bag(bag: str | Path, *, namespace: str = "/", out: str | Path | None = None) -> DeriveResult:
    """Write ``bag`` with the derived topics it lacks into ``out`` (default: in place); BagError if it
    cannot be read or written."""
    bag = Path(bag)
    target = Path(out) if out is not None else bag
    if not bag.exists():
        raise BagError(f"bag {bag} does not exist")
    if out is not None and target.exists():
        raise BagError(f"{target} already exists: choose another output")
    derived = Derived(namespace=namespace, views=True)
    staging = target.parent / f".{target.name}.deriving"
    shutil.rmtree(staging, ignore_errors=True)
    result = DeriveResult(target)
    try:
        with AnyReader([bag], default_typestore=typestore()) as reader:
            present = {c.topic for c in reader.connections}
            if out is None and set(derived.topics()) <= present:
                return result
            # The bag's own definitions for its topics; ours for the derived types it does not define.
            add_types(reader.typestore, set(derived.topics().values()))
            with BagWriter(staging / target.name, typestore=reader.typestore, compression=_compression(bag)) as writer:
                first = {}  # topic -> its first connection (a split bag lists one per file)
                for connection in reader.connections:
                    first.setdefault(connection.topic, connection)
                for connection in first.values():
                    writer.add_topic(connection.topic, connection.msgtype,
                                     offered_qos=getattr(connection.ext, "offered_qos_profiles", None) or [])
                for topic, msgtype, timestamp, data, new in _messages(reader, derived, present):
                    if new and topic not in result.added:
                        writer.add_topic(topic, msgtype, offered_qos=offered_qos(topic))
                        result.added[topic] = 0
                    writer.write_raw(topic, msgtype, timestamp, data)
                    if new:
                        result.added[topic] += 1
    except (AnyReaderError, OSError) as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise BagError(f"cannot derive topics for {bag}: {exc}") from exc
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if out is None and not result.added:
        shutil.rmtree(staging)
        return result
    if out is None:  # the original goes only once the rewrite is complete beside it
        replaced = bag.parent / f".{bag.name}.replaced"
        shutil.rmtree(replaced, ignore_errors=True)
        os.replace(bag, replaced)
        os.replace(staging / target.name, bag)
        shutil.rmtree(replaced)
    else:
        os.replace(staging / target.name, target)
    staging.rmdir()
    return result
