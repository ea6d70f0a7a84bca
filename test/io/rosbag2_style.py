"""Rewrite one of our bags the way `ros2 bag record -s mcap` writes it: the C++-style MCAP writer (here the
independent `mcap` package) with zstd chunks and CRCs, schemas and channels outside the chunks, the
schemas' text taken from the installed .msg files (comments included, as rosbag2's local message
definition source does), and a rosbag2 Jazzy metadata.yaml."""

import os
import re
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import msg_dir, typestore

SEPARATOR = "=" * 80 + "\n"


def msg_text(name: str) -> str:
    package, _, base = name.split("/")
    if package == "m2h_msgs":
        return (msg_dir() / f"{base}.msg").read_text()
    for prefix in os.environ["AMENT_PREFIX_PATH"].split(os.pathsep):
        path = Path(prefix) / "share" / package / "msg" / f"{base}.msg"
        if path.is_file():
            return path.read_text()
    raise FileNotFoundError(name)


def rosbag2_definition(msgtype: str) -> str:
    """Main .msg text, then each dependency as ``MSG: pkg/msg/Name`` sections (rosbag2's layout)."""
    generated, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    deps = re.findall(r"^MSG: (\S+)$", generated, flags=re.M)
    text = msg_text(msgtype)
    for dep in deps:
        package, base = dep.split("/")[0], dep.split("/")[-1]
        text += f"\n{SEPARATOR}MSG: {package}/msg/{base}\n{msg_text(f'{package}/msg/{base}')}"
    return text


def rewrite_as_rosbag2(source: Path, target: Path, *, definitions: dict[str, str] | None = None,
                       split_every: int | None = None) -> Path:
    """Copy every message of ``source`` into a rosbag2-recorded-style bag at ``target``.
    ``definitions`` overrides the schema text of some types (to make a foreign definition);
    ``split_every`` starts a new file (``NAME_1.mcap``, ...) after that many messages, as
    ``ros2 bag record --max-bag-size`` does (each file declares its own schemas and channels)."""
    target.mkdir(parents=True)
    stream = BagStream(source)
    counts: dict[str, int] = {}
    files: list[str] = []
    start, end = None, 0
    out = writer = None
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    for k, message in enumerate(stream.messages()):
        if writer is None or (split_every and k % split_every == 0):
            if writer is not None:
                writer.finish()
                out.close()
            files.append(f"{target.name}_{len(files)}.mcap")
            out = (target / files[-1]).open("wb")
            writer = Writer(out, chunk_size=256 * 1024, compression=CompressionType.ZSTD)
            writer.start(profile="ros2", library="rosbag2-like (mcap python)")
            schemas, channels = {}, {}
        if message.topic not in channels:
            if message.msgtype not in schemas:
                text = (definitions or {}).get(message.msgtype) or rosbag2_definition(message.msgtype)
                schemas[message.msgtype] = writer.register_schema(message.msgtype, "ros2msg", text.encode())
            channels[message.topic] = writer.register_channel(
                message.topic, "cdr", schemas[message.msgtype], metadata={"offered_qos_profiles": "[]"})
        counts[message.topic] = counts.get(message.topic, 0) + 1
        writer.add_message(channels[message.topic], message.log_time, bytes(message.data),
                           message.log_time - 500, sequence=counts[message.topic])
        start = message.log_time if start is None else min(start, message.log_time)
        end = max(end, message.log_time)
    writer.finish()
    out.close()
    store = typestore()
    topics = [{"topic_metadata": {"name": topic, "type": stream.channels[topic].msgtype, "serialization_format": "cdr",
                                  "offered_qos_profiles": [],
                                  "type_description_hash": store.hash_rihs01(stream.channels[topic].msgtype)},
               "message_count": count} for topic, count in counts.items()]
    info = {"version": 9, "storage_identifier": "mcap", "duration": {"nanoseconds": end - start},
            "starting_time": {"nanoseconds_since_epoch": start}, "message_count": sum(counts.values()),
            "topics_with_message_count": topics, "compression_format": "", "compression_mode": "",
            "relative_file_paths": files,
            "files": [{"path": name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": end - start}, "message_count": 0} for name in files],
            "custom_data": {}, "ros_distro": "jazzy"}
    (target / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return target
