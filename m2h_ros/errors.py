"""Every error the project raises on purpose derives from M2HError, so callers can catch one type."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import ParamSpec

P = ParamSpec("P")


class M2HError(Exception):
    """Base class of all m2h_ros errors."""


class ConfigError(M2HError, ValueError):
    """A configuration value (dataclass field, params YAML, CLI option) is invalid."""


class MapError(ConfigError):
    """A robot map (nav2 map.yaml and its image) is unusable: missing, malformed, or not what map_server reads."""


class AudioError(M2HError, ValueError):
    """Audio input is unusable: wrong shape, non-finite samples, silence, bad sample rate."""


class CacheError(M2HError):
    """A cached artefact (RIR bank, sound library, episode file) is missing, stale or corrupt."""


class HeadError(M2HError, ValueError):
    """A head (SOFA HRIR file) is unusable: unreadable, no impulse responses, not two receivers,
    non-finite or all-zero responses, bad source positions, or a sample rate below the simulation's."""


class CheckpointError(M2HError):
    """A checkpoint is missing, corrupt, or does not match the model or settings asked for."""


class BagError(M2HError):
    """A rosbag2 directory or MCAP file is missing, corrupt, or holds unexpected types."""


class EpisodeError(M2HError):
    """An episode file or episode specification is invalid."""


class MicrophoneError(M2HError):
    """No usable audio input: PortAudio missing, no such device, or a device that cannot deliver."""


class PipelineError(M2HError):
    """The node graph broke its step contract: a node stopped answering, or sent unusable data."""


class LiveViewError(M2HError):
    """The live view cannot serve: its address is unusable or its port is taken."""


class VideoError(M2HError):
    """A video cannot be made: the encoder failed or is missing."""


def reports_errors(prog: str) -> Callable[[Callable[P, int | None]], Callable[P, int]]:
    """Decorates a command's ``main``: an M2HError ends it as argparse ends a bad option, with one line
    ``PROG: error: MESSAGE`` on stderr and exit code 2, not a traceback (the error names the problem;
    anything else is a bug and keeps its traceback). A ``main`` that returns None exits 0."""

    def decorate(main: Callable[P, int | None]) -> Callable[P, int]:
        @functools.wraps(main)
        def run(*args: P.args, **kwargs: P.kwargs) -> int:
            try:
                return main(*args, **kwargs) or 0
            except M2HError as exc:
                print(f"{prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
                return 2
        return run
    return decorate
