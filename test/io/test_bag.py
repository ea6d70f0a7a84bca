"""Every m2h_msgs type registers with rosbags, round-trips through a rosbag2 MCAP bag, and has the
same type hash as rosidl generated; broken bags fail with BagError."""

import json
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_share_directory
from msg_values import differences, from_any, sample_values, to_rosbags

from m2h_ros.errors import BagError
from m2h_ros.io.bag import BagWriter, read_messages
from m2h_ros.io.msg_defs import msg_files, typestore

MSG_TYPES = sorted(msg_files())


def test_all_interface_files_are_registered():
    cmake = (Path(__file__).parents[2] / "msg_defs" / "CMakeLists.txt").read_text()
    for name in MSG_TYPES:
        assert f'"msg/{name.rsplit("/", 1)[1]}.msg"' in cmake, f"{name} missing from CMakeLists.txt"
    assert len(MSG_TYPES) >= 9


@pytest.mark.parametrize("msgtype", MSG_TYPES)
def test_type_hash_matches_rosidl(msgtype):
    share = Path(get_package_share_directory("m2h_msgs"))
    generated = json.loads((share / "msg" / f"{msgtype.rsplit('/', 1)[1]}.json").read_text())
    rosidl_hash = next(h["hash_string"] for h in generated["type_hashes"] if h["type_name"] == msgtype)
    assert typestore().hash_rihs01(msgtype) == rosidl_hash


def test_every_type_round_trips_through_mcap(tmp_path):
    store = typestore()
    expected = {name: sample_values(store, name, k) for k, name in enumerate(MSG_TYPES)}
    with BagWriter(tmp_path / "bag") as writer:
        for k, name in enumerate(MSG_TYPES):
            writer.write(f"/probe/{k}", name, 1000 + k, to_rosbags(store, name, expected[name]))
    assert (tmp_path / "bag" / "metadata.yaml").exists()
    assert list((tmp_path / "bag").glob("*.mcap"))
    seen = {}
    for item in read_messages(tmp_path / "bag"):
        seen[item.msgtype] = from_any(item.message)
    assert set(seen) == set(MSG_TYPES)
    for name in MSG_TYPES:
        assert differences(expected[name], seen[name]) == [], name


def test_topic_filter(tmp_path):
    store = typestore()
    name = "m2h_msgs/msg/MotionCommand"
    with BagWriter(tmp_path / "bag") as writer:
        for k in range(3):
            writer.write("/a", name, k, to_rosbags(store, name, sample_values(store, name, k)))
            writer.write("/b", name, k, to_rosbags(store, name, sample_values(store, name, k)))
    assert [m.topic for m in read_messages(tmp_path / "bag", topics=["/b"])] == ["/b"] * 3


def test_existing_bag_is_not_overwritten(tmp_path):
    (tmp_path / "bag").mkdir()
    with pytest.raises(BagError, match="already exists"):
        BagWriter(tmp_path / "bag")


def test_missing_bag(tmp_path):
    with pytest.raises(BagError, match="does not exist"):
        list(read_messages(tmp_path / "nope"))


def test_corrupt_bag(tmp_path):
    store = typestore()
    name = "m2h_msgs/msg/BinauralAudio"
    with BagWriter(tmp_path / "bag") as writer:
        writer.write("/audio", name, 1, to_rosbags(store, name, sample_values(store, name)))
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    mcap.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(BagError):
        list(read_messages(tmp_path / "bag"))


def test_unknown_type_is_refused(tmp_path):
    with BagWriter(tmp_path / "bag") as writer, pytest.raises(BagError, match="unknown message type"):
        writer.write_raw("/x", "nope_msgs/msg/Nope", 0, b"")
