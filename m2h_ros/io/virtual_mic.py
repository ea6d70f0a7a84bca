"""A virtual microphone for machines without a sound card: an ALSA capture device that plays a known
signal at real-time pace (``virtual_mic.c``, an ALSA I/O plugin compiled here on first use).

Everything above ALSA is the real audio stack: a process started with ``VirtualMic.env()`` sees the
device through PortAudio like any card (``capture_node --list-devices`` lists it), so the capture node,
its resampling, stamps and overrun handling are tested as on a robot. ALSA's own ``file`` PCM cannot
stand in: its capture side reads as fast as the reader asks, with no real-time pacing, and the kernel's
loopback card (snd-aloop) needs a module that containers usually lack.

Building needs a C compiler and ALSA's headers: the system's (libasound2-dev) or the ones
``scripts/fetch_audio_libs.sh`` unpacks without root.
"""

from __future__ import annotations

import ctypes.util
import hashlib
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.errors import MicrophoneError
from m2h_ros.io.microphone import FETCH_COMMAND, audio_libs_dir
from m2h_ros.paths import data_dir

SOURCE = Path(__file__).with_name("virtual_mic.c")
SYSTEM_ALSA_CONF = Path("/usr/share/alsa/alsa.conf")
PLUGIN_TYPE = "m2hmic"
# -DPIC: ALSA's headers then build the plugin entry point for dynamic loading.
CFLAGS = ("-shared", "-fPIC", "-DPIC", "-O2", "-Wall")


def _alsa_include_dir() -> Path:
    for root in (Path("/usr/include"), audio_libs_dir() / "usr" / "include"):
        if (root / "alsa" / "pcm_external.h").is_file():
            return root
    raise MicrophoneError(f"ALSA's headers (alsa/pcm_external.h) not found: apt-get install libasound2-dev, "
                          f"or unpack them without root: {FETCH_COMMAND}")


def build_plugin() -> Path:
    """The compiled plugin, built once per source version into the data dir."""
    digest = hashlib.sha256(SOURCE.read_bytes() + " ".join(CFLAGS).encode()).hexdigest()[:16]
    library = data_dir() / "virtual_mic" / digest / f"libasound_module_pcm_{PLUGIN_TYPE}.so"
    if library.is_file():
        return library
    if ctypes.util.find_library("asound") is None:
        raise MicrophoneError("ALSA's library (libasound2) is not installed")
    library.parent.mkdir(parents=True, exist_ok=True)
    partial = library.with_suffix(f".{os.getpid()}.tmp")
    command = ["cc", *CFLAGS, "-o", str(partial), str(SOURCE),
               f"-I{_alsa_include_dir()}", "-l:libasound.so.2"]
    try:
        result = subprocess.run(command, capture_output=True, text=True)
    except FileNotFoundError as exc:
        raise MicrophoneError("no C compiler (cc) to build the virtual microphone") from exc
    if result.returncode != 0:
        raise MicrophoneError(f"building the virtual microphone failed: {' '.join(command)}\n{result.stderr}")
    partial.replace(library)  # atomic: parallel first uses never load a half-written file
    return library


@dataclass(frozen=True)
class VirtualMic:
    name: str          # the ALSA PCM (and PortAudio device) name
    config: Path       # ALSA configuration defining it
    start_file: Path   # CLOCK_REALTIME ns of the signal's first sample, one line per opened stream

    def env(self) -> dict[str, str]:
        """Environment of a process that should see the device (ALSA reads the files in order)."""
        return {"ALSA_CONFIG_PATH": f"{SYSTEM_ALSA_CONF}:{self.config}"}

    def starts_ns(self) -> list[int]:
        return [int(line) for line in self.start_file.read_text().split()] if self.start_file.exists() else []


def virtual_mic(folder: Path, signal: np.ndarray, sample_rate: int, *, name: str = "m2h_virtual_mic") -> VirtualMic:
    """A device in ``folder`` that plays ``signal`` ((samples, channels) float32) at ``sample_rate``,
    then silence."""
    if not SYSTEM_ALSA_CONF.is_file():
        raise MicrophoneError(f"ALSA's configuration {SYSTEM_ALSA_CONF} is missing (install libasound2)")
    signal = np.asarray(signal, "<f4")
    if signal.ndim != 2 or not np.all(np.isfinite(signal)):
        raise MicrophoneError(f"the virtual microphone's signal must be finite (samples, channels), got {signal.shape}")
    plugin = build_plugin()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    raw, starts, config = folder / f"{name}.f32", folder / f"{name}.starts", folder / f"{name}.conf"
    np.ascontiguousarray(signal).tofile(raw)
    starts.unlink(missing_ok=True)
    config.write_text(f'pcm_type.{PLUGIN_TYPE} {{ lib "{plugin}" }}\n'
                      f'pcm.{name} {{\n  type {PLUGIN_TYPE}\n  file "{raw}"\n  rate {int(sample_rate)}\n'
                      f'  channels {signal.shape[1]}\n  start_file "{starts}"\n'
                      f'  hint {{ show on description "m2h virtual microphone" }}\n}}\n')
    return VirtualMic(name, config, starts)
