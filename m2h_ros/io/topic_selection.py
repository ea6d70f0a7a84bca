"""Which topics a recording keeps, and how often: names or shell-style patterns (``/camera/*``) to record
and to leave out, and per-topic rate limits (``TOPIC=HZ``), as ``ros2 bag record`` offers topic
selection and exclusion. ROS-free: the recorder node and the scripts that set it up share it."""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Sequence
from dataclasses import dataclass

from m2h_ros.errors import ConfigError

COMPRESSIONS = ("none", "zstd")  # MCAP chunk compressions a bag may be written with (m2h_ros.io.bag)


def absolute(name: str) -> str:
    """A topic name or pattern as the graph lists it (``camera/*`` -> ``/camera/*``)."""
    return name if name.startswith("/") else "/" + name


def parse_rate_limits(items: Sequence[str], *, setting: str = "max_rate_hz") -> dict[str, float]:
    """``TOPIC=HZ`` items -> {absolute topic or pattern: HZ}; ConfigError naming a malformed item."""
    limits = {}
    for item in items:
        topic, eq, rate = item.rpartition("=")
        try:
            hz = float(rate)
        except ValueError:
            hz = float("nan")
        if not eq or not topic or not (math.isfinite(hz) and hz > 0):
            raise ConfigError(f"{setting}: {item!r} is not TOPIC=HZ with HZ a number > 0 (e.g. "
                              "/camera/rgb/image_raw=2)")
        limits[absolute(topic)] = hz
    return limits


@dataclass(frozen=True)
class TopicSelection:
    topics: tuple[str, ...] = ()  # names or patterns to record; empty: every topic
    exclude: tuple[str, ...] = ()  # names or patterns never to record
    max_rate_hz: tuple[str, ...] = ()  # TOPIC=HZ items

    def __post_init__(self) -> None:
        parse_rate_limits(self.max_rate_hz)

    @staticmethod
    def _matches(topic: str, patterns: Sequence[str]) -> bool:
        return any(fnmatch.fnmatchcase(topic, absolute(p)) for p in patterns)

    def records(self, topic: str) -> bool:
        """Whether ``topic`` (absolute) is to be recorded."""
        return (not self.topics or self._matches(topic, self.topics)) and not self._matches(topic, self.exclude)

    def min_interval_ns(self, topic: str) -> int | None:
        """The shortest time between two recorded messages of ``topic`` (the first limit that matches it),
        or None for no limit."""
        for pattern, hz in parse_rate_limits(self.max_rate_hz).items():
            if fnmatch.fnmatchcase(topic, pattern):
                return round(1e9 / hz)
        return None
