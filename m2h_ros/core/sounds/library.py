"""The sound library: 1 s clips per class, split into heard (train) and unheard (test) sounds.

Built once from real material (``scripts/build_sound_library.py``) into
``data_dir()/sounds/v<LIBRARY_VERSION>/<config fingerprint>/`` as ``heard.npy``, ``unheard.npy``
(float32, rows grouped by class) and ``manifest.json`` (config, and per clip: class, category,
source package and file, offset, licence, gains). ``SoundLibrary.from_folders`` builds the same
object in memory from a user's own folder tree. See docs/design/sound_library.md.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.core.sounds.clips import (
    AUDIO_SUFFIXES,
    clip_power,
    loud_offsets,
    normalise_power,
    read_audio_file,
    spread_picks,
)
from m2h_ros.core.sounds.sources import (
    CLASS_SPECS,
    DEBIAN_PACKAGES,
    ClassSpec,
    SourceFile,
    check_sources,
    list_sources,
    load_source,
    sources_dir,
    stable_seed,
)
from m2h_ros.errors import AudioError, CacheError, ConfigError
from m2h_ros.paths import data_dir

LIBRARY_VERSION = 1
CATEGORIES = ("speech", "music", "background")
TARGET_CATEGORIES = ("speech", "music")  # background sounds are only ever distractors
SPLITS = ("heard", "unheard")
BUILD_COMMAND = "python scripts/build_sound_library.py"


@dataclass(frozen=True)
class SoundLibraryConfig:
    """How the library is cut from its sources; every field is part of the cache key."""

    clips_heard: int = 64  # per class (the scarcest background class bounds it)
    clips_unheard: int = 16  # per class
    seed: int = 0
    sample_rate: int = 16000
    clip_seconds: float = 1.0
    hop_seconds: float = 0.25  # grid of candidate clip starts
    target_power: float = 1.2
    normalisation: str = "dataset"  # "dataset": one gain for all clips; "clip": each clip on its own
    unheard_fraction: float = 0.25  # share of each class's source duration held out as unheard
    max_files_per_class: int | None = None  # None: every file (speech prompts, ambience, loops)
    music_pieces_per_class: int = 24  # scores rendered per music21 class
    music_seconds: float = 40.0  # rendered length of each score
    classes: tuple[str, ...] | None = None  # built-in classes to build (None: all), e.g. a speech-only library

    def __post_init__(self) -> None:
        positive = ("clips_heard", "clips_unheard", "sample_rate", "clip_seconds", "hop_seconds",
                    "target_power", "music_pieces_per_class", "music_seconds")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"SoundLibraryConfig.{name} must be > 0, got {getattr(self, name)!r}")
        if self.normalisation not in ("dataset", "clip"):
            raise ConfigError(f"SoundLibraryConfig.normalisation must be 'dataset' or 'clip', "
                              f"got {self.normalisation!r}")
        if not 0.0 < self.unheard_fraction < 1.0:
            raise ConfigError(f"SoundLibraryConfig.unheard_fraction must be in (0, 1), got {self.unheard_fraction!r}")
        if self.max_files_per_class is not None and self.max_files_per_class < 2:
            raise ConfigError(f"SoundLibraryConfig.max_files_per_class must be None or >= 2, "
                              f"got {self.max_files_per_class!r}")
        if self.music_pieces_per_class < 2:
            raise ConfigError(f"SoundLibraryConfig.music_pieces_per_class must be >= 2, "
                              f"got {self.music_pieces_per_class!r}")
        for name in ("clip_seconds", "hop_seconds"):
            if abs(getattr(self, name) * self.sample_rate - round(getattr(self, name) * self.sample_rate)) > 1e-6:
                raise ConfigError(f"SoundLibraryConfig.{name}={getattr(self, name)!r} is not a whole number of samples")
        if self.clip_len % self.hop:
            raise ConfigError(f"SoundLibraryConfig.hop_seconds={self.hop_seconds!r} must divide "
                              f"clip_seconds={self.clip_seconds!r}")
        if self.classes is not None:
            known = [spec.name for spec in CLASS_SPECS]
            unknown = [name for name in self.classes if name not in known]
            if unknown or not self.classes or len(set(self.classes)) != len(self.classes):
                raise ConfigError(f"SoundLibraryConfig.classes must be distinct names among {known}, "
                                  f"got {self.classes!r}")
        if self.music_seconds < self.clip_seconds:
            raise ConfigError(f"SoundLibraryConfig.music_seconds must be >= clip_seconds, got {self.music_seconds!r}")

    @classmethod
    def small(cls, *, seed: int = 0) -> SoundLibraryConfig:
        """A few clips per class from a few files: builds in seconds, for tests."""
        return cls(clips_heard=4, clips_unheard=2, seed=seed, max_files_per_class=8,
                   music_pieces_per_class=2, music_seconds=5.0)

    @property
    def clip_len(self) -> int:
        return int(round(self.clip_seconds * self.sample_rate))

    @property
    def hop(self) -> int:
        return int(round(self.hop_seconds * self.sample_rate))

    def clips_per_class(self, split: str) -> int:
        return self.clips_heard if split == "heard" else self.clips_unheard

    def fingerprint(self) -> str:
        """Cache key: the config, the library format version and the pinned source packages."""
        text = json.dumps({"config": dataclasses.asdict(self), "version": LIBRARY_VERSION,
                           "packages": DEBIAN_PACKAGES}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class ClipInfo:
    """Where one clip came from. ``row`` indexes ``clips(split)``; gains map raw source audio to the clip."""

    clip_id: str  # "<class>/<split>/<k>"
    split: str
    row: int
    category: str
    cls: str
    package: str
    licence: str
    source_file: str
    offset_s: float
    raw_power: float  # mean power of the window in the decoded source, before normalisation
    file_power: float  # mean power of the whole decoded source file
    gain: float


@dataclass(frozen=True)
class _Source:
    """A loadable source file of one class and split (built-in or user folder)."""

    source_file: str
    package: str
    licence: str
    load: Callable[[], np.ndarray]


def _check_split(split: str) -> None:
    if split not in SPLITS:
        raise ConfigError(f"split must be one of {SPLITS}, got {split!r}")


class SoundLibrary:
    """Clips of every class, per split; arrays are memory-mapped when loaded from disk."""

    def __init__(self, *, config: SoundLibraryConfig, arrays: dict[str, np.ndarray],
                 infos: Sequence[ClipInfo], path: Path | None = None, fingerprint: str | None = None,
                 present: frozenset[str] | None = None) -> None:
        self.config = config
        self.path = path
        # None: every clip. Else the ids whose audio is there (a partial library, core/sounds/partial.py);
        # the arrays' other rows are unset and any access to them raises CacheError.
        self.present = present
        # Identifies the clips (cache keys of episodes etc.): the config's for the built-in library,
        # config + file contents for a folder library.
        self.fingerprint = fingerprint or config.fingerprint()
        self._arrays = arrays
        self._infos = {split: tuple(i for i in infos if i.split == split) for split in SPLITS}
        self._by_id = {info.clip_id: info for info in infos}
        classes: dict[str, str] = {}
        self._ranges: dict[tuple[str, str], tuple[int, int]] = {}
        for split in SPLITS:
            for info in self._infos[split]:
                classes.setdefault(info.cls, info.category)
                start, _ = self._ranges.get((split, info.cls), (info.row, info.row))
                self._ranges[(split, info.cls)] = (start, info.row + 1)
        self._category_of = classes
        self.classes: tuple[str, ...] = tuple(classes)
        self.categories: tuple[str, ...] = tuple(c for c in CATEGORIES if c in classes.values())

    # ----------------------------------------------------------------- queries
    def category_of(self, cls: str) -> str:
        if cls not in self._category_of:
            raise ConfigError(f"unknown sound class {cls!r}; classes: {self.classes}")
        return self._category_of[cls]

    def classes_of(self, category: str) -> tuple[str, ...]:
        if category not in self.categories:
            raise ConfigError(f"unknown sound category {category!r}; categories: {self.categories}")
        return tuple(c for c in self.classes if self._category_of[c] == category)

    def _rows(self, split: str, category: str | None, cls: str | None) -> slice:
        """Rows are grouped by class and classes by category, so every selection is one slice."""
        _check_split(split)
        if cls is not None:
            if category is not None and self.category_of(cls) != category:
                raise ConfigError(f"class {cls!r} is in category {self.category_of(cls)!r}, not {category!r}")
            return slice(*self._ranges[(split, cls)])
        if category is None:
            return slice(0, len(self._infos[split]))
        members = self.classes_of(category)
        return slice(self._ranges[(split, members[0])][0], self._ranges[(split, members[-1])][1])

    @property
    def complete(self) -> bool:
        return self.present is None

    def _absent(self, what: str) -> CacheError:
        return CacheError(f"{what}: the sound library at {self.path} holds only the {len(self.present)} clips "
                          f"of the episodes it was cut for; build the whole library with `{BUILD_COMMAND}`")

    def clips(self, split: str = "heard", category: str | None = None, cls: str | None = None) -> np.ndarray:
        """(n, clip_len) float32 clips of a split, optionally of one category or class (a view, not a copy)."""
        if not self.complete:
            raise self._absent(f"all {split} clips")
        return self._arrays[split][self._rows(split, category, cls)]

    def infos(self, split: str = "heard", category: str | None = None, cls: str | None = None) -> tuple[ClipInfo, ...]:
        """Metadata of the rows ``clips`` returns for the same arguments, in the same order."""
        return self._infos[split][self._rows(split, category, cls)]

    def info(self, clip_id: str) -> ClipInfo:
        if clip_id not in self._by_id:
            raise ConfigError(f"unknown clip id {clip_id!r}")
        return self._by_id[clip_id]

    def clip(self, clip_id: str) -> np.ndarray:
        """A copy of one clip, by id."""
        info = self.info(clip_id)
        if not self.complete and clip_id not in self.present:
            raise self._absent(f"clip {clip_id}")
        return np.array(self._arrays[info.split][info.row])

    def sample_id(self, rng: np.random.Generator, *, category: str, split: str = "heard",
                  cls: str | None = None) -> str:
        """Draw a clip id: a class uniformly among the category's (or ``cls``), then a clip uniformly in it."""
        if cls is None:
            members = self.classes_of(category)
            cls = members[int(rng.integers(len(members)))]
        rows = self._rows(split, category, cls)
        return self._infos[split][int(rng.integers(rows.start, rows.stop))].clip_id

    def sample(self, rng: np.random.Generator, *, category: str, split: str = "heard",
               cls: str | None = None) -> tuple[np.ndarray, str]:
        """``sample_id``'s draw and the clip."""
        clip_id = self.sample_id(rng, category=category, split=split, cls=cls)
        return self.clip(clip_id), clip_id

    # ------------------------------------------------------------ disk cache
    @staticmethod
    def path_for(config: SoundLibraryConfig) -> Path:
        return data_dir() / "sounds" / f"v{LIBRARY_VERSION}" / config.fingerprint()

    @staticmethod
    def build_command(config: SoundLibraryConfig) -> str:
        if config == SoundLibraryConfig():
            return BUILD_COMMAND
        if config == SoundLibraryConfig.small():
            return f"{BUILD_COMMAND} --small"
        return f"SoundLibrary.build({config!r})"

    @classmethod
    def load(cls, config: SoundLibraryConfig | None = None) -> SoundLibrary:
        """Open a built library (memory-mapped); CacheError, naming the build command, if missing or corrupt."""
        config = config or SoundLibraryConfig()
        path = cls.path_for(config)
        hint = f"build it with `{cls.build_command(config)}`"
        manifest_path = path / "manifest.json"
        if not manifest_path.is_file():
            raise CacheError(f"no sound library at {path}: {hint}")
        try:
            manifest = json.loads(manifest_path.read_text())
            infos = [ClipInfo(**clip) for clip in manifest["clips"]]
            if manifest["version"] != LIBRARY_VERSION or manifest["fingerprint"] != config.fingerprint():
                raise ValueError("version or fingerprint does not match the config")
            arrays = {split: np.load(path / f"{split}.npy", mmap_mode="r") for split in SPLITS}
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise CacheError(f"sound library at {path} is corrupt ({error}): delete it and {hint}") from error
        for split, array in arrays.items():
            rows = sum(info.split == split for info in infos)
            if array.dtype != np.float32 or array.shape != (rows, config.clip_len):
                raise CacheError(f"sound library at {path} is corrupt ({split}.npy is {array.dtype} "
                                 f"{array.shape}, manifest says float32 ({rows}, {config.clip_len})): "
                                 f"delete it and {hint}")
        return cls(config=config, arrays=arrays, infos=infos, path=path)

    @classmethod
    def build(cls, config: SoundLibraryConfig | None = None, *, sources: Path | None = None,
              progress: bool = True) -> SoundLibrary:
        """Cut the library from the fetched Debian packages and the music21 corpus, write it atomically, load it."""
        config = config or SoundLibraryConfig()
        root = sources or sources_dir()
        check_sources(root)
        started = time.perf_counter()
        plan = [(spec, _builtin_split(spec, root, config)) for spec in CLASS_SPECS
                if config.classes is None or spec.name in config.classes]
        arrays, infos = _cut(config, [(spec.category, spec.name, splits) for spec, splits in plan],
                             progress=progress)
        manifest = _manifest(config, infos, extra={
            "sources_dir": str(root),
            "classes": [{"category": spec.category, "name": spec.name, "package": spec.package_label(),
                         "licence": spec.licence,
                         "files": {split: [s.source_file for s in splits[split]] for split in SPLITS}}
                        for spec, splits in plan],
            "software": _software_versions(),
            "build_seconds": round(time.perf_counter() - started, 2),
        })
        final = cls.path_for(config)
        _write_atomically(final, arrays, manifest)
        return cls.load(config)

    @classmethod
    def from_folders(cls, root: Path | str, *, config: SoundLibraryConfig | None = None,
                     progress: bool = False) -> SoundLibrary:
        """Build a library in memory from ``root/<category>/<class>/<heard|unheard>/*.{wav,flac,ogg}``.

        Categories must be among speech, music, background; files at any sample rate are resampled,
        multi-channel files averaged to mono. ``config`` sets clips per class, seed and normalisation.
        """
        config = config or SoundLibraryConfig()
        root = Path(root)
        if not root.is_dir():
            raise ConfigError(f"sound folder root {root} is not a directory")
        classes = []
        digests: list[str] = []
        for category_dir in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
            if category_dir.name not in CATEGORIES:
                raise ConfigError(f"unknown sound category folder {category_dir}: use {CATEGORIES}")
            for class_dir in sorted(p for p in category_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
                classes.append((category_dir.name, class_dir.name, _folder_split(class_dir, config, digests)))
        if not classes:
            raise ConfigError(f"no <category>/<class>/ folders under {root} (categories: {CATEGORIES})")
        names = [name for _, name, _ in classes]
        if len(set(names)) != len(names):
            raise ConfigError(f"class names must be unique across categories under {root}: {sorted(names)}")
        classes.sort(key=lambda c: CATEGORIES.index(c[0]))
        arrays, infos = _cut(config, classes, progress=progress)
        fingerprint = hashlib.sha256("\n".join([config.fingerprint(), *digests]).encode()).hexdigest()[:16]
        return cls(config=config, arrays=arrays, infos=infos, path=None, fingerprint=fingerprint)


# ---------------------------------------------------------------- building
def _builtin_split(spec: ClassSpec, root: Path, config: SoundLibraryConfig) -> dict[str, list[_Source]]:
    """Shuffle a class's files with the seed, keep the configured number, hold out ~unheard_fraction of duration."""
    files = list_sources(spec, root, min_seconds=config.clip_seconds, music_seconds=config.music_seconds)
    rng = np.random.default_rng([config.seed, stable_seed(spec.category, spec.name, "split")])
    files = [files[i] for i in rng.permutation(len(files))]
    limit = config.music_pieces_per_class if spec.kind == "music21" else config.max_files_per_class
    files = files[:limit] if limit else files
    durations = np.array([f.duration for f in files])
    # Unheard takes files until it holds its share of the duration, then heard gets the rest.
    unheard_count = int(np.searchsorted(np.cumsum(durations), config.unheard_fraction * durations.sum()) + 1)
    unheard_count = min(unheard_count, len(files) - 1)
    package = spec.package_label()

    def source(f: SourceFile) -> _Source:
        return _Source(f.path, package, spec.licence, lambda: load_source(f, root, sample_rate=config.sample_rate))

    return {"unheard": [source(f) for f in files[:unheard_count]],
            "heard": [source(f) for f in files[unheard_count:]]}


def _folder_split(class_dir: Path, config: SoundLibraryConfig, all_digests: list[str]) -> dict[str, list[_Source]]:
    """The class's heard/ and unheard/ files; appends "<class>/<split>/<name> <sha256>" to ``all_digests``."""
    splits: dict[str, list[_Source]] = {}
    digests: dict[str, str] = {}
    for split in SPLITS:
        split_dir = class_dir / split
        files = sorted(p for p in split_dir.glob("*") if p.suffix.lower() in AUDIO_SUFFIXES) if split_dir.is_dir() else []
        if not files:
            raise AudioError(f"class folder {class_dir} has no audio files in {split}/ "
                             f"(expected {split}/*.wav, *.flac or *.ogg)")
        for path in files:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            if digests.get(digest, split) != split:
                raise ConfigError(f"{path} has the same content as a file in {digests[digest]}/: "
                                  f"heard and unheard must not share source files")
            digests[digest] = split
            all_digests.append(f"{class_dir.name}/{split}/{path.name} {digest}")
        splits[split] = [_Source(str(path), "user folder", "as provided by the user",
                                 lambda path=path: read_audio_file(path, sample_rate=config.sample_rate))
                         for path in files]
    return splits


def _cut(config: SoundLibraryConfig, classes: list[tuple[str, str, dict[str, list[_Source]]]], *,
         progress: bool) -> tuple[dict[str, np.ndarray], list[ClipInfo]]:
    """Take the clips of every class and split, then normalise their power over the whole dataset."""
    from tqdm import tqdm  # noqa: PLC0415

    raw: dict[str, list[np.ndarray]] = {split: [] for split in SPLITS}
    fields: dict[str, list[dict]] = {split: [] for split in SPLITS}
    jobs = [(category, name, split, splits[split]) for category, name, splits in classes for split in SPLITS]
    with tqdm(total=sum(len(sources) for *_, sources in jobs), desc="sound library", unit="file",
              disable=not progress) as bar:
        for category, name, split, sources in jobs:
            bar.set_postfix_str(f"{name}/{split}")
            clips, metas = _cut_class_split(config, category, name, split, sources, on_file=bar.update)
            raw[split].append(clips)
            first_row = len(fields[split])
            fields[split].extend(dict(meta, row=first_row + k) for k, meta in enumerate(metas))
    # Rows are grouped by class (in category order) within each split; one gain over both splits.
    normalised, gains = normalise_power(np.concatenate([np.concatenate(raw[split]) for split in SPLITS]),
                                        target=config.target_power, mode=config.normalisation)
    count = len(fields["heard"])
    arrays = {"heard": normalised[:count], "unheard": normalised[count:]}
    infos = [ClipInfo(**meta, gain=float(gain))
             for meta, gain in zip(fields["heard"] + fields["unheard"], gains, strict=True)]
    return arrays, infos


def _cut_class_split(config: SoundLibraryConfig, category: str, name: str, split: str,
                     sources: list[_Source], *, on_file: Callable[[], object]) -> tuple[np.ndarray, list[dict]]:
    rng = np.random.default_rng([config.seed, stable_seed(category, name, split)])
    audio, candidates = [], []
    for source in sources:
        signal = source.load()
        if not np.isfinite(signal).all():
            raise AudioError(f"{source.source_file} holds NaN or infinite samples")
        audio.append(signal)
        candidates.append(loud_offsets(signal, clip_len=config.clip_len, hop=config.hop))
        on_file()
    wanted = config.clips_per_class(split)
    try:
        picks = spread_picks(candidates, wanted, stride=config.clip_len // config.hop, hop=config.hop, rng=rng)
    except ConfigError as error:
        raise ConfigError(f"class {name!r} ({split}, {len(sources)} files): {error}; lower "
                          f"clips_{split} or add material") from error
    clips = np.stack([audio[f][start:start + config.clip_len] for f, start in picks]).astype(np.float32)
    powers = clip_power(clips)
    metas = [{"clip_id": f"{name}/{split}/{k:04d}", "split": split, "category": category,
              "cls": name, "package": sources[f].package, "licence": sources[f].licence,
              "source_file": sources[f].source_file, "offset_s": start / config.sample_rate,
              "raw_power": float(power), "file_power": float(np.mean(np.square(audio[f])))}
             for k, ((f, start), power) in enumerate(zip(picks, powers, strict=True))]
    return clips, metas


def _manifest(config: SoundLibraryConfig, infos: list[ClipInfo], *, extra: dict) -> dict:
    return {"format": "m2h_ros sound library", "version": LIBRARY_VERSION, "fingerprint": config.fingerprint(),
            "config": dataclasses.asdict(config), "debian_packages": DEBIAN_PACKAGES, **extra,
            "clips": [dataclasses.asdict(info) for info in infos]}


def _software_versions() -> dict[str, str]:
    from importlib.metadata import version  # noqa: PLC0415

    return {name: version(name) for name in ("music21", "tinysoundfont", "g722", "numpy", "scipy", "soundfile")}


def _write_atomically(final: Path, arrays: dict[str, np.ndarray], manifest: dict) -> None:
    """Write into a temp dir beside ``final`` and rename it, so readers never see a half-built library."""
    final.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=final.parent))
    try:
        for split, array in arrays.items():
            np.save(staging / f"{split}.npy", array)
        (staging / "manifest.json").write_text(json.dumps(manifest, indent=1))
        if final.exists():  # a rebuild (e.g. after corruption) replaces the old one
            shutil.rmtree(final)
        os.rename(staging, final)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
