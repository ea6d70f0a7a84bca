"""Shared fixtures. Each test gets a ROS_DOMAIN_ID of its own and localhost-only discovery, and every
process a graph test starts is stopped (SIGINT, then SIGKILL) when the test ends."""

import faulthandler
import os
import random
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

# Before any test imports torch: idle OpenMP threads sleep instead of spinning on the shared cores.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))  # for the shared helpers module

from ros_domains import DOMAINS, domain_in_use  # noqa: E402  (found through the path above)


_next_domain = 0  # set by pytest_configure
_terminal_stderr = 2  # the terminal's stderr, duplicated before any test's output capture replaces fd 2


def pytest_configure(config):
    global _terminal_stderr, _next_domain
    _terminal_stderr = os.dup(2)
    # The run's own domain (module fixtures' runs) and where the first test looks for a free one.
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random(os.getpid() ^ time.time_ns()).randint(1, DOMAINS)))
    _next_domain = int(os.environ["ROS_DOMAIN_ID"])
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    # A suite started in the background of a non-interactive shell inherits SIGINT ignored, and so would
    # every process it starts (an ignored signal stays ignored across exec): the tests stop them with it.
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def ros_domain(monkeypatch):
    """Each test on a domain of its own, the next that no participant on this machine holds: nodes of an
    earlier test still shutting down, or of another test run, cannot reach into it."""
    global _next_domain
    for _ in range(DOMAINS):
        domain, _next_domain = _next_domain, _next_domain % DOMAINS + 1
        if not domain_in_use(domain):
            break
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    yield


@pytest.fixture(autouse=True)
def no_endless_hang(request):
    """pytest-timeout's signal cannot break a wait inside native code (a DDS call of a test's own rclpy
    node): two minutes past its limit the suite ends with every thread's traceback instead of hanging."""
    faulthandler.dump_traceback_later(float(request.config.getini("timeout")) + 120, exit=True,
                                      file=_terminal_stderr)
    yield
    faulthandler.cancel_dump_traceback_later()


class Processes:
    """Starts processes in their own session and guarantees they are gone afterwards."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []

    def start(self, args: list[str], **kwargs) -> subprocess.Popen:
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, **kwargs)
        self.procs.append(proc)
        return proc

    @staticmethod
    def interrupt(proc: subprocess.Popen, *, timeout: float = 15.0,
                  signum: signal.Signals = signal.SIGINT) -> tuple[int, str, str]:
        """SIGINT (or ``signum``), wait; returns (returncode, stdout, stderr). Kills the group if it hangs."""
        if proc.poll() is None:
            proc.send_signal(signum)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
            pytest.fail(f"{proc.args} did not exit within {timeout} s of {signum.name}:\n{err}")
        return proc.returncode, out, err

    def cleanup(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGINT)
                    proc.wait(timeout=5)
                except (subprocess.TimeoutExpired, ProcessLookupError):
                    try:
                        os.killpg(proc.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    proc.wait()


@pytest.fixture
def processes():
    procs = Processes()
    yield procs
    procs.cleanup()


def write_sound_folders(root: Path, *, seconds: float = 3.0, sample_rate: int = 16000) -> Path:
    """A tiny user-style sound folder tree (root/<category>/<class>/<split>/*.wav) of synthetic
    tones and noise bursts: enough for episode and environment tests that need no real audio."""
    import numpy as np
    import soundfile

    rng = np.random.default_rng(0)
    t = np.arange(int(seconds * sample_rate)) / sample_rate
    kinds = {"speech": ("voice_a", "voice_b"), "music": ("tones_a", "tones_b"), "background": ("hiss",)}
    for category, classes in kinds.items():
        for c, cls in enumerate(classes):
            for s, (split, files) in enumerate((("heard", 3), ("unheard", 2))):
                folder = root / category / cls / split
                folder.mkdir(parents=True, exist_ok=True)
                for k in range(s * 3, s * 3 + files):  # distinct files in heard and unheard
                    envelope = 0.5 + 0.5 * np.sin(2 * np.pi * (0.7 + k) * t) ** 2
                    if category == "background":
                        audio = rng.standard_normal(t.size) * 0.1
                    else:
                        f0 = 150 + 90 * c + 40 * k + (300 if category == "music" else 0)
                        audio = sum(np.sin(2 * np.pi * f0 * h * t) / h for h in range(1, 5)) * envelope
                    soundfile.write(folder / f"{cls}_{k}.wav", audio.astype(np.float32), sample_rate)
    return root


@pytest.fixture(scope="session")
def folder_library(tmp_path_factory):
    """A SoundLibrary built in memory from synthetic folders (a few clips per class)."""
    from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig

    root = write_sound_folders(tmp_path_factory.mktemp("sound_folders"))
    return SoundLibrary.from_folders(root, config=SoundLibraryConfig(clips_heard=4, clips_unheard=2))


@pytest.fixture(scope="session")
def sound_sources() -> Path:
    """The extracted Debian sound packages (fetched once by scripts/fetch_sound_sources.sh)."""
    from m2h_ros.core.sounds.sources import check_sources, sources_dir
    from m2h_ros.errors import CacheError

    root = sources_dir()
    try:
        check_sources(root)
    except CacheError as missing:
        # Said, not silent: the run needs the network and some minutes once per data folder.
        warnings.warn(f"fetching the sound sources for the tests of the real library ({missing}): "
                      f"scripts/fetch_sound_sources.sh {root}", stacklevel=1)
        subprocess.run(["bash", str(ROOT / "scripts" / "fetch_sound_sources.sh"), str(root)], check=True)
    return root


@pytest.fixture(scope="session")
def small_data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("m2h_data")


@pytest.fixture(scope="session")
def small_library(sound_sources, small_data_dir):
    """The --small library of real material (a few clips per class), built once per session."""
    from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("M2H_DATA_DIR", str(small_data_dir))
        return SoundLibrary.build(SoundLibraryConfig.small(), sources=sound_sources, progress=False)


@pytest.fixture(scope="session")
def speech_under_music(small_library):
    """known_mixture.speech_under_music of the small library: (stereo mixture, reference) at 16 kHz."""
    from known_mixture import speech_under_music

    return speech_under_music(small_library)


@pytest.fixture(scope="session")
def fast_acoustics():
    """Short RIRs, image sources up to order 2, no ray-traced tail: a small scene's bank builds in ~1 s."""
    from m2h_ros.core.world.acoustics import AcousticsConfig

    return AcousticsConfig(rir_length=0.25, early_length=0.064, ism_max_order=2, tail=False)
