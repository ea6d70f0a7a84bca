"""Our bags follow rosbag2 Jazzy's conventions and an independent reader (the `mcap` package with
`mcap-ros2-support`, as Foxglove's tools use) decodes them message for message."""

import dataclasses
import os

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from m2h_ros import topics
from m2h_ros.io.bag import BagWriter
from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import typestore
from m2h_ros.io.synthetic import IMAGE_SIZE, SyntheticRun, write_synthetic_run

RELIABLE_LATCHED = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                       QosTime(0, 0), QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


@pytest.fixture(scope="module")
def run_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp("interop") / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/" + topics.EPISODE, "m2h_msgs/msg/EpisodeInfo", offered_qos=[RELIABLE_LATCHED])
        write_synthetic_run(bag, SyntheticRun(episodes=1, max_steps=2), writer=writer)
    return bag


def plain(value):
    """A rosbags or mcap_ros2 message (or field) -> nested plain Python values for comparison."""
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.name.islower() and f.name != "__msgtype__"}
    if hasattr(value, "__slots__") and not isinstance(value, str | bytes):
        return {name: plain(getattr(value, name)) for name in value.__slots__ if not name.startswith("_")}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, bytes | bytearray):
        return list(value)
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


def test_metadata_follows_rosbag2_jazzy(run_bag):
    info = yaml.safe_load((run_bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    store = typestore()
    entries = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert "/" + topics.REFINED in entries and "/" + topics.RGB in entries
    for name, entry in entries.items():
        meta = entry["topic_metadata"]
        assert meta["serialization_format"] == "cdr"
        assert meta["type_description_hash"] == store.hash_rihs01(meta["type"]), name
        assert isinstance(meta["offered_qos_profiles"], list)
    (latched,) = entries["/" + topics.EPISODE]["topic_metadata"]["offered_qos_profiles"]
    assert latched["durability"] == "transient_local" and latched["reliability"] == "reliable"
    assert sum(e["message_count"] for e in entries.values()) == info["message_count"]
    assert info["ros_distro"] == (os.environ.get("ROS_DISTRO") or "jazzy")


# What rosbag2_storage_mcap (jazzy) puts in a channel's metadata for one reliable, transient-local
# publisher: yaml-cpp's dump of the QoS list (block style, no final newline), then the type hash.
ROSBAG2_QOS_TEXT = """- history: keep_last
  depth: 1
  reliability: reliable
  durability: transient_local
  deadline:
    sec: 0
    nsec: 0
  lifespan:
    sec: 0
    nsec: 0
  liveliness: automatic
  liveliness_lease_duration:
    sec: 0
    nsec: 0
  avoid_ros_namespace_conventions: false"""


def test_channels_carry_rosbag2_jazzy_metadata(run_bag):
    store = typestore()
    with next(run_bag.glob("*.mcap")).open("rb") as stream:
        reader = make_reader(stream)
        channels = {c.topic: c for c in reader.get_summary().channels.values()}
        schemas = reader.get_summary().schemas
        (record,) = [m for m in reader.iter_metadata() if m.name == "rosbag2"]
    for topic, channel in channels.items():
        assert list(channel.metadata) == ["offered_qos_profiles", "topic_type_hash"], topic
        assert channel.metadata["topic_type_hash"] == store.hash_rihs01(schemas[channel.schema_id].name)
    assert channels["/" + topics.EPISODE].metadata["offered_qos_profiles"] == ROSBAG2_QOS_TEXT
    assert channels["/" + topics.AUDIO].metadata["offered_qos_profiles"] == "[]"  # no publisher's QoS known
    listed = yaml.safe_load(record.metadata["serialized_metadata"])
    assert listed == yaml.safe_load((run_bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def test_independent_reader_decodes_every_message(run_bag):
    store = typestore()
    ours = [(m.topic, m.log_time, plain(store.deserialize_cdr(m.data, m.msgtype)))
            for m in BagStream(run_bag).messages()]
    theirs = []
    with next(run_bag.glob("*.mcap")).open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(ours)
        for schema in summary.schemas.values():
            assert schema.encoding == "ros2msg"
        for channel in summary.channels.values():
            assert channel.message_encoding == "cdr" and "offered_qos_profiles" in channel.metadata
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            theirs.append((channel.topic, message.log_time, plain(decoded)))
            if channel.topic == "/" + topics.RGB:
                assert schema.name == "sensor_msgs/msg/Image"
                assert (decoded.encoding, decoded.height, decoded.width) == ("rgb8", IMAGE_SIZE, IMAGE_SIZE)
                assert len(decoded.data) == IMAGE_SIZE * IMAGE_SIZE * 3
            if channel.topic == "/" + topics.DEPTH:
                assert decoded.encoding == "32FC1" and decoded.step == 4 * IMAGE_SIZE
    assert len(theirs) == len(ours)
    for (topic, stamp, a), (topic_b, stamp_b, b) in zip(ours, theirs, strict=True):
        assert (topic, stamp) == (topic_b, stamp_b)
        assert _close(a, b), topic


def _close(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float):
        return a == b or (np.isnan(a) and np.isnan(b))
    return a == b
