"""The m2h_msgs definitions, registered with rosbags so recorded runs decode without ROS installed, and
the released definitions of the standard types a bag carries whose packages the PyPI wheels lack.
Any other type (a robot's drivers publish their own) is read from its installed package's
``share/<package>/msg/<Name>.msg`` on ``AMENT_PREFIX_PATH``, as rosbag2 finds it, when a bag first
needs it.

Those are pinned by their RIHS01 type hash (the hash the released Jazzy package's rosidl build gives; the
test suite recomputes it from the released .msg text with rosidl's own generator): a bag written here is
wire- and hash-compatible with the real package. They are registered with the bag writer only, never
installed as a Python or ament package, so they cannot shadow the real one where ROS 2 has it.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from functools import lru_cache
from pathlib import Path

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore, get_types_from_msg
from rosbags.typesys.store import Typestore

from m2h_ros.errors import BagError
from m2h_ros.paths import PACKAGE_DIR

PACKAGE = "m2h_msgs"

# foxglove_msgs/msg/RawAudio as released (foxglove_msgs 3.2.0 to 3.4.3 carry the same text), comments
# left out (they do not enter the hash). Foxglove's Audio panel plays it.
RAW_AUDIO = "foxglove_msgs/msg/RawAudio"
RELEASED_DEFINITIONS = {
    RAW_AUDIO: """builtin_interfaces/Time timestamp
uint8[] data
string format
uint32 sample_rate
uint32 number_of_channels
""",
}
# tf2_msgs/msg/TFMessage comes with rosbags' Jazzy store; its hash is pinned all the same.
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
RELEASED_HASHES = {
    TF_MESSAGE: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    RAW_AUDIO: "RIHS01_0b99ed3750364a2dcec27d8bf046f1b7c212ca9a5d26542819e08e83d62e3025",
}


def msg_dir() -> Path:
    """Folder holding m2h_msgs' .msg files: the source tree, else an installed share/m2h_msgs/msg."""
    candidates = [PACKAGE_DIR.parent / "msg_defs" / "msg"]
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        candidates.append(Path(prefix) / "share" / PACKAGE / "msg")
    for folder in candidates:
        if any(folder.glob("*.msg")):
            return folder
    raise BagError(f"no {PACKAGE} .msg files found in {', '.join(map(str, candidates))}")


def msg_files() -> dict[str, Path]:
    """Full type name (``m2h_msgs/msg/Name``) to its .msg file."""
    return {f"{PACKAGE}/msg/{p.stem}": p for p in sorted(msg_dir().glob("*.msg"))}


@lru_cache(maxsize=1)
def typestore() -> Typestore:
    """A Jazzy typestore that also knows every m2h_msgs type and the released types above."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name, path in msg_files().items():
        types.update(get_types_from_msg(path.read_text(), name))
    for name, text in RELEASED_DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    for name, pinned in RELEASED_HASHES.items():
        if store.hash_rihs01(name) != pinned:
            raise BagError(f"{name}: this definition hashes to {store.hash_rihs01(name)}, the released "
                           f"package's is {pinned}; bags would not match it")
    return store


def installed_msg_file(msgtype: str) -> Path | None:
    """``share/<package>/msg/<Name>.msg`` of ``<package>/msg/<Name>`` in the first prefix of
    ``AMENT_PREFIX_PATH`` that installs it, else None."""
    package, kind, name = (msgtype.split("/") + ["", ""])[:3]
    if kind != "msg" or not package or not name:
        return None
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        path = Path(prefix) / "share" / package / "msg" / f"{name}.msg"
        if path.is_file():
            return path
    return None


def _referenced(field: tuple) -> list[str]:
    """The message type names a rosbags field description refers to."""
    kind, detail = field
    if kind == Nodetype.NAME:
        return [detail]
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return _referenced(detail[0])
    return []


def add_types(store: Typestore, names: Iterable[str]) -> None:
    """Register in ``store`` each of ``names`` and every type they refer to that it lacks, as this project's
    typestore defines them (a store read from a bag holds only the bag's types)."""
    ours, found = typestore(), {}
    pending = list(names)
    while pending:
        name = pending.pop()
        if name in store.fielddefs or name in found:
            continue
        found[name] = ours.fielddefs[name]
        pending += [ref for _, field in found[name][1] for ref in _referenced(field)]
    store.register(found)


def ensure_known(store: Typestore, msgtype: str) -> None:
    """Make ``store`` know ``msgtype``: if it does not, register it from its installed definition, with
    every type it refers to that the store lacks; BagError naming the first one that no installed
    package defines."""
    found: dict = {}
    pending = [msgtype]
    while pending:
        name = pending.pop()
        if name in store.types or name in found:
            continue
        path = installed_msg_file(name)
        if path is None:
            needed = "" if name == msgtype else f" (needed by {msgtype})"
            raise BagError(f"unknown message type {name!r}{needed}: not a Jazzy standard type and no installed "
                           f"package on AMENT_PREFIX_PATH has its .msg file")
        types = get_types_from_msg(path.read_text(), name)
        found.update(types)
        pending += [ref for _, fields in types.values() for _, field in fields for ref in _referenced(field)]
    store.register(found)
