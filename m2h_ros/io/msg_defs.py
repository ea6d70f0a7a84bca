"""The m2h_msgs definitions, registered with rosbags so recorded runs decode without ROS installed."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from rosbags.typesys import Stores, get_typestore, get_types_from_msg
from rosbags.typesys.store import Typestore

from m2h_ros.errors import BagError
from m2h_ros.paths import PACKAGE_DIR

PACKAGE = "m2h_msgs"


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
    """A Jazzy typestore that also knows every m2h_msgs type."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name, path in msg_files().items():
        types.update(get_types_from_msg(path.read_text(), name))
    store.register(types)
    return store
