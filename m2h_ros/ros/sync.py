"""Gathers the messages of one step from several topics (no ordering between topics in ROS).

Messages of our own types carry (episode_id, step); standard ones (Odometry, Image) carry only the
step's stamp, shared by every message the simulator publishes for that step. ``bind`` ties a stamp
to its (episode_id, step) when a message that carries both arrives; stamped parts wait until then.
When every required part of a step is in, ``on_complete(key, parts)`` runs once.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Iterable
from typing import Any

StepKey = tuple[str, int]


class StepAssembler:
    def __init__(self, required: Iterable[str], on_complete: Callable[[StepKey, dict[str, Any]], None], *,
                 max_pending: int = 64) -> None:
        self.required = frozenset(required)
        self.on_complete, self.max_pending = on_complete, max_pending
        self.pending: OrderedDict[StepKey, dict[str, Any]] = OrderedDict()
        self.by_stamp: OrderedDict[int, dict[str, Any]] = OrderedDict()  # parts waiting for bind()
        self.keys: OrderedDict[int, StepKey] = OrderedDict()  # stamp -> key

    def add(self, key: StepKey, part: str, value: Any) -> None:
        parts = self.pending.setdefault(key, {})
        parts[part] = value
        self._trim(self.pending)
        if self.required <= parts.keys():
            del self.pending[key]
            self.on_complete(key, parts)

    def add_stamped(self, stamp_ns: int, part: str, value: Any) -> None:
        key = self.keys.get(stamp_ns)
        if key is not None:
            self.add(key, part, value)
            return
        self.by_stamp.setdefault(stamp_ns, {})[part] = value
        self._trim(self.by_stamp)

    def bind(self, stamp_ns: int, key: StepKey) -> None:
        self.keys[stamp_ns] = key
        self._trim(self.keys)
        for part, value in self.by_stamp.pop(stamp_ns, {}).items():
            self.add(key, part, value)

    def _trim(self, table: OrderedDict) -> None:
        while len(table) > self.max_pending:  # steps that can never complete (a node restarted)
            table.popitem(last=False)


class EpisodeGate:
    """EpisodeInfo by episode id, for steps that need it: a step that completes before its episode's
    (latched, but separately delivered) info waits for it; ``on_step(key, parts, info)`` runs then."""

    def __init__(self, on_step: Callable[[StepKey, dict[str, Any], Any], None]) -> None:
        self.on_step = on_step
        self.infos: dict[str, Any] = {}
        self.parked: list[tuple[StepKey, dict[str, Any]]] = []

    def add_info(self, info: Any) -> None:
        self.infos[info.episode_id] = info
        parked, self.parked = self.parked, []
        for key, parts in parked:
            self.step(key, parts)

    def step(self, key: StepKey, parts: dict[str, Any]) -> None:
        info = self.infos.get(key[0])
        if info is None:
            self.parked.append((key, parts))
        else:
            self.on_step(key, parts, info)
