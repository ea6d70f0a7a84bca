"""Microphones through PortAudio (the `sounddevice` package): find the library, list and pick input
devices, and run an input stream whose blocks carry their capture time.

PortAudio comes from the system (``apt-get install libportaudio2``) or, without root, from the
packages ``scripts/fetch_audio_libs.sh`` unpacks into the data dir (``scripts/setup.sh`` runs it).
The audio callback runs on PortAudio's thread and only copies: each block goes into a bounded queue
with its stamp and whether samples were lost before it (a PortAudio overrun, or blocks the queue had
no room for); the consumer drains the queue on its own thread.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.errors import MicrophoneError
from m2h_ros.paths import data_dir

FETCH_COMMAND = "bash scripts/fetch_audio_libs.sh"


def audio_libs_dir() -> Path:
    """Where scripts/fetch_audio_libs.sh unpacks PortAudio, JACK's client library and ALSA's headers."""
    return data_dir() / "audio_libs" / "root"


def _unpacked(name: str) -> Path | None:
    return next(iter(sorted(audio_libs_dir().glob(f"usr/lib/*/{name}"))), None)


_sounddevice = None


def sounddevice():
    """The `sounddevice` module, loaded against the system's PortAudio or the unpacked one."""
    global _sounddevice
    if _sounddevice is not None:
        return _sounddevice
    if ctypes.util.find_library("portaudio") is None:
        library = _unpacked("libportaudio.so.2")
        if library is None:
            raise MicrophoneError(f"PortAudio not found: install libportaudio2 (apt-get install libportaudio2) "
                                  f"or unpack it without root: {FETCH_COMMAND}")
        # libportaudio links libjack.so.0: loaded first by path, the loader finds it by its soname.
        jack = _unpacked("libjack.so.0")
        if jack is not None and ctypes.util.find_library("jack") is None:
            ctypes.CDLL(str(jack), mode=ctypes.RTLD_GLOBAL)
        # sounddevice asks ctypes.util.find_library for "portaudio" while it imports; answer it once.
        system_lookup = ctypes.util.find_library
        ctypes.util.find_library = lambda name: str(library) if name == "portaudio" else system_lookup(name)
        try:
            import sounddevice as module
        finally:
            ctypes.util.find_library = system_lookup
    else:
        import sounddevice as module
    _sounddevice = module
    return module


@dataclass(frozen=True)
class InputDevice:
    index: int
    name: str
    host_api: str
    channels: int         # input channels
    default_rate: int
    is_default: bool

    def line(self) -> str:
        mark = "*" if self.is_default else " "
        return f"{mark} {self.index:3d}  {self.name}  ({self.host_api}, {self.channels} in, {self.default_rate} Hz)"


def input_devices() -> list[InputDevice]:
    sd = sounddevice()
    default = sd.default.device[0]
    apis = sd.query_hostapis()
    return [InputDevice(i, d["name"], apis[d["hostapi"]]["name"], int(d["max_input_channels"]),
                        int(d["default_samplerate"]), i == default)
            for i, d in enumerate(sd.query_devices()) if d["max_input_channels"] > 0]


def device_listing() -> str:
    devices = input_devices()
    if not devices:
        return "no audio input device found (PortAudio sees none with input channels)"
    return "\n".join(["input devices (* = default):", *(d.line() for d in devices)])


def find_device(spec: str) -> InputDevice:
    """An input device by index ("3"), by (part of) its name, or the default one for ""."""
    devices = input_devices()
    if not devices:
        raise MicrophoneError("no audio input device found: PortAudio sees no device with input channels "
                              "(is a microphone connected, and is this user allowed to open it?)")
    if spec == "":
        chosen = [d for d in devices if d.is_default] or devices[:1]
    elif spec.isdigit():
        chosen = [d for d in devices if d.index == int(spec)]
    else:
        chosen = [d for d in devices if d.name == spec] or [d for d in devices if spec.lower() in d.name.lower()]
    if len(chosen) != 1:
        what = "no" if not chosen else f"{len(chosen)}"
        raise MicrophoneError(f"{what} input device(s) match {spec!r}; " + device_listing())
    return chosen[0]


@dataclass(frozen=True)
class Block:
    samples: np.ndarray  # (channels, n) float32, the picked channels in the order asked
    stamp_ns: int        # capture time of the first sample
    gap: bool            # samples were lost just before this block


class Microphone:
    """An open input stream of the picked ``channels`` (0-based) of ``device``; call ``blocks()`` to
    drain what arrived. ``notify`` is called on PortAudio's thread after each block is queued."""

    def __init__(self, device: InputDevice, *, channels: tuple[int, ...], sample_rate: int, block_s: float,
                 queue_s: float, buffer_s: float, clock_ns: Callable[[], int] = time.time_ns,
                 notify: Callable[[], None] = lambda: None):
        if not channels or max(channels) >= device.channels or min(channels) < 0:
            raise MicrophoneError(f"channels {list(channels)} of {device.name!r}, which has {device.channels} "
                                  f"input channel(s) (0-based)")
        self.device, self.channels, self.sample_rate = device, tuple(channels), sample_rate
        self.clock_ns, self.notify = clock_ns, notify
        block = max(1, round(block_s * sample_rate))
        self._queue: queue.Queue[Block] = queue.Queue(maxsize=max(2, round(queue_s / block_s)))
        self._lock = threading.Lock()
        self._gap = False
        self.overruns = 0       # PortAudio reported input overflow (samples lost before the callback)
        self.lost_blocks = 0    # blocks the queue had no room for (the consumer fell behind)
        sd = sounddevice()
        try:
            self._stream = sd.InputStream(device=device.index, channels=max(channels) + 1,
                                          samplerate=sample_rate, blocksize=block, dtype="float32",
                                          # a deep device buffer: an input's blocks still arrive as they
                                          # fill, and a busy machine overruns it far less often
                                          latency=buffer_s, callback=self._callback)
            self._stream.start()
        except sd.PortAudioError as exc:
            raise MicrophoneError(f"cannot open {device.name!r} at {sample_rate} Hz with "
                                  f"{max(channels) + 1} channel(s): {exc}") from exc

    def _callback(self, indata, frames, time_info, status) -> None:
        now = self.clock_ns()
        # PortAudio's estimate of when the block's first sample reached the converter, where it gives
        # one; otherwise the block's own length (its first sample is at least that old).
        age = time_info.currentTime - time_info.inputBufferAdcTime
        if not 0.0 <= age < 1.0:
            age = frames / self.sample_rate
        with self._lock:
            if status.input_overflow:
                self.overruns += 1
                self._gap = True
            block = Block(np.ascontiguousarray(indata[:, self.channels].T), now - round(age * 1e9), self._gap)
            try:
                self._queue.put_nowait(block)
                self._gap = False
            except queue.Full:
                self.lost_blocks += 1
                self._gap = True
        self.notify()

    def blocks(self) -> list[Block]:
        out = []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out

    @property
    def latency_s(self) -> float:
        return float(self._stream.latency)

    def close(self) -> None:
        self._stream.abort()
        self._stream.close()
