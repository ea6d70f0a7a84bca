"""The real sound material of the built-in library: which files make each class, and how to decode them.

Every class comes from a Debian package fetched by ``scripts/fetch_sound_sources.sh`` (extracted
into :func:`sources_dir`, never installed system-wide) or from the music21 corpus rendered with a
General MIDI soundfont. Each :class:`SourceFile` carries its package and licence, which the library
manifest records for every clip.
"""

from __future__ import annotations

import glob
import hashlib
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.core.sounds.clips import read_audio_file, resample
from m2h_ros.errors import AudioError, CacheError
from m2h_ros.paths import data_dir

FETCH_COMMAND = "bash scripts/fetch_sound_sources.sh"

# Pinned Debian packages (package -> version); scripts/fetch_sound_sources.sh pins the same (a test
# checks it). A new version is new material, so the versions are part of the library's cache key.
DEBIAN_PACKAGES: dict[str, str] = {
    "asterisk-core-sounds-en-g722": "1.6.1-1",
    "asterisk-core-sounds-es-g722": "1.6.1-1",
    "asterisk-core-sounds-fr-g722": "1.6.1-1",
    "asterisk-core-sounds-it-g722": "1.6.1-1",
    "asterisk-core-sounds-ru-g722": "1.6.1-1",
    "asterisk-moh-opsound-g722": "2.03-1.1",
    "timgm6mb-soundfont": "1.3-5",
    "megaglest-data": "3.13.0-3",
    "lincity-ng-data": "2.9~git20150314-5",
}

SOUNDFONT = "usr/share/sounds/sf2/TimGM6mb.sf2"
G722_BYTES_PER_SECOND = 8000  # 64 kbit/s
MUSIC21_PREFIX = "music21:"


def sources_dir() -> Path:
    """Where the fetch script extracts the packages: ``$M2H_SOUND_SOURCES`` or ``data_dir()/sound_sources``."""
    root = os.environ.get("M2H_SOUND_SOURCES")
    return Path(root).expanduser() if root else data_dir() / "sound_sources"


@dataclass(frozen=True)
class ClassSpec:
    """One built-in class: its files (globs under the sources root, or music21 corpus folders)."""

    category: str
    name: str
    package: str  # Debian package (or "music21") the audio comes from
    licence: str
    kind: str  # "g722" | "audio_file" | "music21"
    patterns: tuple[str, ...]
    programs: tuple[int, ...] = ()  # music21: General MIDI program of part i (cycled)
    bpm: float = 100.0  # music21: quarter notes per minute

    def package_label(self) -> str:
        """Package name and exact version, as the manifest records it."""
        if self.kind == "music21":
            import music21  # noqa: PLC0415  (heavy; only needed for music)

            return f"music21=={music21.__version__} corpus + timgm6mb-soundfont={DEBIAN_PACKAGES['timgm6mb-soundfont']}"
        return f"{self.package}={DEBIAN_PACKAGES[self.package]}"


_SPEECH = "usr/share/asterisk/sounds"
_MEGAGLEST = "usr/share/games/megaglest/tilesets/*/sounds"
_LINCITY = "usr/share/games/lincity-ng/sounds"
_MUSIC_LICENCE = "score: music21 corpus (BSD-3-Clause, public-domain works); timbre: TimGM6mb soundfont (GPL-2)"

CLASS_SPECS: tuple[ClassSpec, ...] = (
    ClassSpec("speech", "en_female", "asterisk-core-sounds-en-g722", "CC-BY-SA-3.0 (Allison Smith)",
              "g722", (f"{_SPEECH}/en_US_f_Allison/**/*.g722",)),
    ClassSpec("speech", "es_female", "asterisk-core-sounds-es-g722", "CC-BY-SA-3.0 (Allison Smith)",
              "g722", (f"{_SPEECH}/es_MX_f_Allison/**/*.g722",)),
    ClassSpec("speech", "fr_female", "asterisk-core-sounds-fr-g722", "CC-BY-SA-3.0 (June Wallack)",
              "g722", (f"{_SPEECH}/fr_CA_f_June/**/*.g722",)),
    ClassSpec("speech", "it_male", "asterisk-core-sounds-it-g722", "CC-BY-3.0 (Carlo Flora)",
              "g722", (f"{_SPEECH}/it_IT_m_Carlo/**/*.g722",)),
    ClassSpec("speech", "ru_female", "asterisk-core-sounds-ru-g722", "CC-BY-3.0 (Maxim Topal)",
              "g722", (f"{_SPEECH}/ru_RU_f_IvrvoiceRU/**/*.g722",)),
    ClassSpec("music", "piano", "music21", _MUSIC_LICENCE, "music21", ("bach/*.mxl",), (0,), bpm=84.0),
    ClassSpec("music", "strings", "music21", _MUSIC_LICENCE, "music21", ("palestrina/*.krn",),
              (40, 41, 42, 43), bpm=150.0),
    ClassSpec("music", "winds", "music21", _MUSIC_LICENCE, "music21", ("monteverdi/*.mxl",),
              (73, 68, 71, 70, 60), bpm=110.0),
    ClassSpec("music", "guitar", "music21", _MUSIC_LICENCE, "music21", ("trecento/*.xml",), (24,),
              bpm=160.0),
    ClassSpec("music", "recordings", "asterisk-moh-opsound-g722",
              "CC-BY-SA-3.0 (Macroform, Manolo Camp, Reno Project)", "g722",
              ("usr/share/asterisk/moh/*.g722",)),
    ClassSpec("background", "birds", "megaglest-data", "CC-BY-SA-3.0 (MegaGlest Team)", "audio_file",
              (f"{_MEGAGLEST}/day.ogg", f"{_MEGAGLEST}/sunny_day.ogg", f"{_MEGAGLEST}/desertday.ogg")),
    ClassSpec("background", "night_insects", "megaglest-data", "CC-BY-SA-3.0 (MegaGlest Team)",
              "audio_file", (f"{_MEGAGLEST}/night.ogg", f"{_MEGAGLEST}/nightime.ogg")),
    ClassSpec("background", "rain_wind", "megaglest-data", "CC-BY-SA-3.0 (MegaGlest Team)", "audio_file",
              (f"{_MEGAGLEST}/rain.ogg", f"{_MEGAGLEST}/rain.wav", f"{_MEGAGLEST}/wind.ogg")),
    ClassSpec("background", "traffic", "lincity-ng-data", "GPL-2+ (LinCity-NG authors)", "audio_file",
              (f"{_LINCITY}/Trafic*.wav", f"{_LINCITY}/RailTrain*.wav", f"{_LINCITY}/DirtTrack*.wav",
               f"{_LINCITY}/Harbor*.wav")),
    ClassSpec("background", "industry", "lincity-ng-data", "GPL-2+ (LinCity-NG authors)", "audio_file",
              tuple(f"{_LINCITY}/{name}*.wav" for name in
                    ("Industry", "CoalMine", "OreMine", "Mill", "Blacksmith", "PowerCoal"))),
)


@dataclass(frozen=True)
class SourceFile:
    """One source recording (or corpus score) of a class; ``path`` is relative to the sources root."""

    spec: ClassSpec
    path: str
    duration: float  # seconds; for scores the rendered length asked for


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def stable_seed(*parts: str) -> int:
    """A seed derived from names that is the same in every process (``hash()`` is salted)."""
    return zlib.crc32("/".join(parts).encode())


def check_sources(root: Path) -> None:
    """Raise CacheError unless every pinned package is extracted under ``root``."""
    missing = [pkg for pkg, version in DEBIAN_PACKAGES.items()
               if not (root / "markers" / pkg).is_file()
               or (root / "markers" / pkg).read_text().strip() != version]
    if missing:
        raise CacheError(f"sound sources missing or outdated in {root}: {', '.join(missing)}; "
                         f"run `{FETCH_COMMAND}` first")


def list_sources(spec: ClassSpec, root: Path, *, min_seconds: float, music_seconds: float) -> list[SourceFile]:
    """The class's distinct files (duplicates by content dropped), sorted by path, at least ``min_seconds`` long."""
    if spec.kind == "music21":
        from music21 import corpus  # noqa: PLC0415

        corpus_dir = Path(corpus.getPaths()[0]).parent.parent
        paths = sorted({str(p.relative_to(corpus_dir)) for pattern in spec.patterns
                        for p in corpus_dir.glob(pattern)})
        return [SourceFile(spec, MUSIC21_PREFIX + p, music_seconds) for p in paths]
    found = sorted({Path(p) for pattern in spec.patterns
                    for p in glob.glob(str(root / "root" / pattern), recursive=True)
                    if "/silence/" not in p})  # asterisk's silence/ prompts hold no speech
    files, seen = [], set()
    for path in found:
        digest = _sha256(path)
        if digest in seen:  # megaglest ships the same ambience under several tilesets
            continue
        seen.add(digest)
        if spec.kind == "g722":
            duration = path.stat().st_size / G722_BYTES_PER_SECOND
        else:
            import soundfile  # noqa: PLC0415

            duration = soundfile.info(str(path)).duration
        if duration >= min_seconds:
            files.append(SourceFile(spec, str(path.relative_to(root / "root")), duration))
    if len(files) < 2:
        raise CacheError(f"class {spec.name!r}: found {len(files)} usable files under {root} "
                         f"(need 2 to split heard/unheard); run `{FETCH_COMMAND}`")
    return files


def decode_g722(data: bytes) -> np.ndarray:
    """64 kbit/s G.722 (16 kHz wideband) to float64 samples in [-1, 1)."""
    import G722  # noqa: PLC0415  (PyPI g722)

    return np.asarray(G722.G722(16000, 64000).decode(data), dtype=np.float64) / 32768.0


def render_score(corpus_path: str, *, programs: tuple[int, ...], bpm: float, seconds: float,
                 sample_rate: int, soundfont: Path) -> np.ndarray:
    """Render the first ``seconds`` of a music21 corpus score, part i on General MIDI ``programs[i % len]``."""
    import tinysoundfont  # noqa: PLC0415
    from music21 import chord, corpus  # noqa: PLC0415

    score = corpus.parse(corpus_path)
    score.stripTies(inPlace=True)  # a copy would cost most of the render time
    seconds_per_quarter = 60.0 / bpm
    events = []  # (sample, is_on, channel, key, velocity); note-offs sort before note-ons at a tie
    for channel, part in enumerate(score.parts[:15]):
        channel = channel + (channel >= 9)  # channel 9 is General MIDI drums
        for element in part.flatten().notes:
            start = int(round(float(element.offset) * seconds_per_quarter * sample_rate))
            stop = int(round(float(element.offset + element.quarterLength) * seconds_per_quarter * sample_rate))
            if start >= seconds * sample_rate or stop <= start:
                continue
            velocity = int(element.volume.velocity or 80)
            keys = [p.midi for p in element.pitches] if isinstance(element, chord.Chord) else [element.pitch.midi]
            for key in keys:
                events.append((start, 1, channel, key, velocity))
                events.append((stop, 0, channel, key, 0))
    if not events:
        raise AudioError(f"music21 score {corpus_path!r} has no notes")
    synth = tinysoundfont.Synth(samplerate=sample_rate)
    sfid = synth.sfload(str(soundfont))
    for channel in range(16):
        synth.program_select(channel, sfid, 0, programs[(channel - (channel > 9)) % len(programs)])
    total = int(seconds * sample_rate)
    out = np.zeros((total, 2), dtype=np.float32)
    position = 0
    for sample, is_on, channel, key, velocity in sorted(events):
        sample = min(sample, total)
        if sample > position:
            out[position:sample] = np.frombuffer(synth.generate_simple(sample - position), np.float32).reshape(-1, 2)
            position = sample
        if is_on:
            synth.noteon(channel, key, velocity)
        else:
            synth.noteoff(channel, key)
    if position < total:  # let the last notes ring out
        out[position:] = np.frombuffer(synth.generate_simple(total - position), np.float32).reshape(-1, 2)
    return out.mean(axis=1, dtype=np.float64)


def load_source(source: SourceFile, root: Path, *, sample_rate: int) -> np.ndarray:
    """Decode (or render) one source to mono float64 at ``sample_rate``."""
    spec = source.spec
    if spec.kind == "music21":
        return render_score(source.path.removeprefix(MUSIC21_PREFIX), programs=spec.programs, bpm=spec.bpm,
                            seconds=source.duration, sample_rate=sample_rate,
                            soundfont=root / "root" / SOUNDFONT)
    path = root / "root" / source.path
    if spec.kind == "g722":
        audio = decode_g722(path.read_bytes())
        return resample(audio, 16000, sample_rate)
    return read_audio_file(path, sample_rate=sample_rate)
