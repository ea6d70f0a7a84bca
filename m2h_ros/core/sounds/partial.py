"""A sound library holding only the clips some episodes play, cut without building the whole library.

The whole library (``scripts/build_sound_library.py``) decodes every source file of every class and
normalises the clips' power over the whole set, so no clip can be cut on its own from the sources
alone. The shipped **index** (``library_index.json``: every clip's class, split, source file, offset
and gain, written from a full build by ``scripts/build_sound_library.py --write-index``) holds what
that build decided; with it:

* ``index_library(config)`` is a library with every clip's metadata and no audio: enough to draw
  episodes (``episodes_for``), which then match the whole library's exactly (same fingerprint);
* ``build_partial(config, clip_ids)`` decodes only the source files of those clips and cuts them
  exactly as the full build does (the same samples, bit for bit; each clip's window power is checked
  against the index), into ``sounds/v<N>/<fingerprint>-partial/``, adding to what is there;
* ``load_partial(config)`` opens it. Only the pipeline's simulator accepts a partial library
  (``sim_world.sound_library``): training and evaluation read whole classes and keep asking for the
  full build. A partial library's clip outside its set raises CacheError naming the build command.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from m2h_ros.core.sounds.clips import clip_power
from m2h_ros.core.sounds.library import (BUILD_COMMAND, LIBRARY_VERSION, SPLITS, ClipInfo, SoundLibrary,
                                         SoundLibraryConfig, _write_atomically)
from m2h_ros.core.sounds.sources import CLASS_SPECS, SourceFile, check_sources, load_source, sources_dir
from m2h_ros.errors import CacheError

INDEX_PATH = Path(__file__).with_name("library_index.json")
INDEX_FORMAT = "m2h_ros sound library index"
POWER_RTOL = 1e-5  # a cut clip's window power against the index's: the same decode gives the same samples


def write_index(library: SoundLibrary, path: Path = INDEX_PATH) -> Path:
    """Write the index of a complete built-in library (what ``build_partial`` needs to cut its clips)."""
    if not library.complete:
        raise CacheError("an index is written from the whole library, not a partial one")
    infos = [info for split in SPLITS for info in library.infos(split)]
    document = {"format": INDEX_FORMAT, "version": LIBRARY_VERSION, "fingerprint": library.fingerprint,
                "config": dataclasses.asdict(library.config), "clips": [dataclasses.asdict(i) for i in infos]}
    path.write_text(json.dumps(document, separators=(",", ":")) + "\n")
    return path


def read_index(config: SoundLibraryConfig, path: Path = INDEX_PATH) -> list[ClipInfo]:
    """The clips of ``config``'s library as the index records them; CacheError if it is for another."""
    try:
        document = json.loads(path.read_text())
        infos = [ClipInfo(**clip) for clip in document["clips"]]
        fingerprint, version = document["fingerprint"], document["version"]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise CacheError(f"sound library index {path} is unreadable ({error}); build the whole library "
                         f"with `{BUILD_COMMAND}`") from error
    if version != LIBRARY_VERSION or fingerprint != config.fingerprint():
        raise CacheError(f"sound library index {path} is of library {fingerprint} v{version}, not "
                         f"{config.fingerprint()} v{LIBRARY_VERSION}: rewrite it with `{BUILD_COMMAND} "
                         f"--write-index` or build the whole library")
    return infos


def partial_path(config: SoundLibraryConfig) -> Path:
    full = SoundLibrary.path_for(config)
    return full.with_name(f"{full.name}-partial")


def _library(config: SoundLibraryConfig, infos: Sequence[ClipInfo], clips: dict[str, np.ndarray],
             path: Path | None) -> SoundLibrary:
    # np.zeros is calloc'd: the absent rows cost address space, not memory.
    arrays = {split: np.zeros((sum(i.split == split for i in infos), config.clip_len), np.float32)
              for split in SPLITS}
    by_id = {info.clip_id: info for info in infos}
    for clip_id, clip in clips.items():
        arrays[by_id[clip_id].split][by_id[clip_id].row] = clip
    return SoundLibrary(config=config, arrays=arrays, infos=infos, path=path, present=frozenset(clips))


def index_library(config: SoundLibraryConfig, *, index: Path = INDEX_PATH) -> SoundLibrary:
    """Every clip's metadata, no audio: for drawing episodes before their clips are cut."""
    return _library(config, read_index(config, index), {}, None)


def load_partial(config: SoundLibraryConfig) -> SoundLibrary:
    """The partial library of ``config`` on disk; CacheError if there is none or it is corrupt."""
    path = partial_path(config)
    if not (path / "manifest.json").is_file():
        raise CacheError(f"no partial sound library at {path}")
    try:
        manifest = json.loads((path / "manifest.json").read_text())
        infos = [ClipInfo(**clip) for clip in manifest["clips"]]
        present = manifest["present"]
        if manifest["version"] != LIBRARY_VERSION or manifest["fingerprint"] != config.fingerprint():
            raise ValueError("version or fingerprint does not match the config")
        clips = np.load(path / "clips.npy")
        if clips.dtype != np.float32 or clips.shape != (len(present), config.clip_len):
            raise ValueError(f"clips.npy is {clips.dtype} {clips.shape} for {len(present)} clips")
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise CacheError(f"partial sound library at {path} is corrupt ({error}): delete it") from error
    return _library(config, infos, dict(zip(present, clips, strict=True)), path)


def build_partial(config: SoundLibraryConfig, clip_ids: Iterable[str], *, index: Path = INDEX_PATH,
                  sources: Path | None = None) -> SoundLibrary:
    """Cut ``clip_ids`` (plus what the partial library on disk holds) from the sources; write, return it."""
    infos = read_index(config, index)
    by_id = {info.clip_id: info for info in infos}
    unknown = sorted(set(clip_ids) - by_id.keys())
    if unknown:
        raise CacheError(f"clips {unknown[:3]} are not in the sound library index {index}")
    try:
        existing = load_partial(config)
        clips = {clip_id: existing.clip(clip_id) for clip_id in sorted(existing.present)}
    except CacheError:
        clips = {}
    wanted = sorted(set(clip_ids) - clips.keys())
    if wanted:
        root = sources or sources_dir()
        check_sources(root)
        specs = {spec.name: spec for spec in CLASS_SPECS}
        by_file: dict[tuple[str, str], list[ClipInfo]] = {}
        for clip_id in wanted:
            info = by_id[clip_id]
            by_file.setdefault((info.cls, info.source_file), []).append(info)
        for (cls, source_file), members in by_file.items():
            audio = load_source(SourceFile(specs[cls], source_file, config.music_seconds), root,
                                sample_rate=config.sample_rate)
            for info in members:
                clips[info.clip_id] = _cut_clip(audio, info, config)
    library_path = partial_path(config)
    present = sorted(clips)
    manifest = {"format": "m2h_ros partial sound library", "version": LIBRARY_VERSION,
                "fingerprint": config.fingerprint(), "config": dataclasses.asdict(config),
                "present": present, "clips": [dataclasses.asdict(i) for i in infos]}
    _write_atomically(library_path, {"clips": np.stack([clips[c] for c in present]) if present
                                     else np.zeros((0, config.clip_len), np.float32)}, manifest)
    return load_partial(config)


def _cut_clip(audio: np.ndarray, info: ClipInfo, config: SoundLibraryConfig) -> np.ndarray:
    """The full build's clip: the window at the recorded offset, times the dataset gain, as float32."""
    start = int(round(info.offset_s * config.sample_rate))
    window = audio[start:start + config.clip_len].astype(np.float32)
    power = float(clip_power(window[None])[0]) if len(window) == config.clip_len else float("nan")
    if not np.isclose(power, info.raw_power, rtol=POWER_RTOL, atol=0.0):
        raise CacheError(f"clip {info.clip_id}: {info.source_file} at {info.offset_s} s decodes to window power "
                         f"{power:.6g}, the index says {info.raw_power:.6g} (other decoder versions?); build the "
                         f"whole library with `{BUILD_COMMAND}`")
    return (window[None] * np.array([info.gain])[:, None]).astype(np.float32)[0]
