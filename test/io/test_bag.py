"""Every m2h_msgs type registers with rosbags, round-trips through a rosbag2 MCAP bag, and has the
same type hash as rosidl generated; broken bags fail with BagError."""

import json
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from msg_values import differences, from_any, sample_values, to_rosbags

from m2h_ros.errors import BagError
from m2h_ros.io.bag import BagWriter, read_messages
from m2h_ros.io.msg_defs import RELEASED_HASHES, msg_files, typestore

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
    assert list(read_messages(tmp_path / "bag", topics=["/not_recorded"])) == []


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
    with BagWriter(tmp_path / "bag") as writer, pytest.raises(BagError, match="/x: unknown message type"):
        writer.write_raw("/x", "nope_msgs/msg/Nope", 0, b"")


def installed_package(prefix: Path, package: str, files: dict[str, str]) -> None:
    folder = prefix / "share" / package / "msg"
    folder.mkdir(parents=True)
    for name, text in files.items():
        (folder / f"{name}.msg").write_text(text)


def test_a_robots_own_type_is_read_from_its_installed_package(tmp_path, monkeypatch):
    """A driver's type (not a Jazzy standard one) comes from share/<package>/msg on AMENT_PREFIX_PATH,
    with the types it refers to; an independent reader decodes it from the bag's own schema."""
    installed_package(tmp_path / "robot", "robot_msgs", {
        "Reading": "std_msgs/Header header\nPart[] parts\nPart[2] pair\nuint8[] data\n",
        "Part": "string name\nfloat32 value\n"})
    installed_package(tmp_path / "later", "robot_msgs", {"Part": "float64 shadowed\n"})  # the first prefix wins
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{tmp_path / 'robot'}:{tmp_path / 'later'}")
    store = get_typestore(Stores.ROS2_JAZZY)
    with BagWriter(tmp_path / "bag", typestore=store) as writer:
        writer.add_topic("/reading", "robot_msgs/msg/Reading")
        Part, Reading = store.types["robot_msgs/msg/Part"], store.types["robot_msgs/msg/Reading"]
        Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
        message = Reading(header=Header(stamp=Time(sec=3, nanosec=4), frame_id="mic"),
                          parts=[Part(name="left", value=0.5)], pair=[Part(name="a", value=1.0), Part(name="b", value=2.0)],
                          data=np.arange(5, dtype=np.uint8))
        writer.write("/reading", "robot_msgs/msg/Reading", 7, message)
    with AnyReader([tmp_path / "bag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        (connection, _, raw), = reader.messages()
        got = reader.deserialize(raw, connection.msgtype)
    assert (got.header.frame_id, got.header.stamp.sec) == ("mic", 3)
    assert [(p.name, p.value) for p in got.parts + got.pair] == [("left", 0.5), ("a", 1.0), ("b", 2.0)]
    assert got.data.tolist() == [0, 1, 2, 3, 4]


def test_a_type_whose_parts_no_package_defines_is_named(tmp_path, monkeypatch):
    installed_package(tmp_path / "robot", "robot_msgs", {"Reading": "Missing part\n"})
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "robot"))
    with BagWriter(tmp_path / "bag", typestore=get_typestore(Stores.ROS2_JAZZY)) as writer, \
            pytest.raises(BagError, match=r"/r: unknown message type 'robot_msgs/msg/Missing' \(needed by "
                                          r"robot_msgs/msg/Reading\)"):
        writer.add_topic("/r", "robot_msgs/msg/Reading")


# The released .msg files, verbatim: tf2_msgs (geometry2, jazzy branch) and foxglove_msgs 3.4.3
# (foxglove-sdk tag ros-v3.4.3, ros/src/foxglove_msgs/ros2/RawAudio.msg; unchanged since 3.2.0).
RELEASED_MSG_TEXT = {
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "foxglove_msgs/msg/RawAudio": """# foxglove_msgs/msg/RawAudio
# A single block of an audio bitstream

# Generated by https://github.com/foxglove/foxglove-sdk

# Timestamp of the start of the audio block
builtin_interfaces/Time timestamp

# Audio data. The samples in the data must be interleaved and little-endian
uint8[] data

# Audio format. Only 'pcm-s16' is currently supported
string format

# Sample rate in Hz
uint32 sample_rate

# Number of channels in the audio block
uint32 number_of_channels
""",
}


def rosidl_hash(msgtype: str, text: str, work: Path) -> str:
    """The RIHS01 hash rosidl's own generator gives a .msg text, as a package build would."""
    from rosidl_adapter.msg import convert_msg_to_idl
    from rosidl_generator_type_description import generate_type_hash

    package, _, name = msgtype.split("/")
    (work / package / "msg").mkdir(parents=True)
    (work / package / "msg" / f"{name}.msg").write_text(text)
    convert_msg_to_idl(work / package, package, Path("msg") / f"{name}.msg", work / "idl" / "msg")
    share = Path(get_package_share_directory("std_msgs")).parent
    args = {"package_name": package, "output_dir": str(work / "out"), "idl_tuples": [f"{work / 'idl'}:msg/{name}.idl"],
            "include_paths": [f"{dep}:{share / dep}" for dep in ("builtin_interfaces", "std_msgs", "geometry_msgs")]}
    (work / "args.json").write_text(json.dumps(args))
    (generated,) = generate_type_hash(str(work / "args.json"))
    return json.loads(generated.read_text())["type_hashes"][0]["hash_string"]


@pytest.mark.parametrize("msgtype", sorted(RELEASED_MSG_TEXT))
def test_released_types_hash_as_the_released_packages(msgtype, tmp_path):
    expected = rosidl_hash(msgtype, RELEASED_MSG_TEXT[msgtype], tmp_path)
    assert RELEASED_HASHES[msgtype] == expected
    assert typestore().hash_rihs01(msgtype) == expected

