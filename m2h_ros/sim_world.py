"""What the simulator plays, from its configuration: the sound library, the episode list and the
environment settings. ROS-free, so the sim node, ``scripts/run_pipeline.py`` (which builds the data
before any node starts) and the tests all derive the same episodes from the same SimConfig."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from m2h_ros.core.sounds import partial
from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.camera import CameraConfig
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import Episode, EpisodeConfig, episodes_for
from m2h_ros.errors import CacheError
from m2h_ros.node_configs import SimConfig

# "fast": short RIRs, image sources to order 2, no late tail: seconds per scene, for tests and quick
# looks at the graph, never for results.
ACOUSTICS_PRESETS = {"default": AcousticsConfig(),
                     "fast": AcousticsConfig(rir_length=0.25, early_length=0.064, ism_max_order=2, tail=False)}
EPISODE_FILE_SIZE = 1000  # episodes per file (the paper's test-set size)


def sound_library(name: str, *, build: bool = False) -> SoundLibrary:
    """"" = the full built-in library (or, when only that exists, the partial one the main job cuts:
    core/sounds/partial.py), "small" = its test-size variant, else a folder of
    <category>/<class>/<heard|unheard>/*.wav (SoundLibrary.from_folders). ``build``: build a missing
    built-in library instead of raising CacheError."""
    if name not in ("", "small"):
        return SoundLibrary.from_folders(Path(name))
    config = SoundLibraryConfig.small() if name == "small" else SoundLibraryConfig()
    try:
        return SoundLibrary.load(config)
    except CacheError:
        if name == "" and not build:
            try:
                return partial.load_partial(config)
            except CacheError:
                pass
        if not build:
            raise
        print("building the sound library (first run only, a few minutes)", flush=True)
        return SoundLibrary.build(config)


def prepare_library(config: SimConfig) -> SoundLibrary:
    """A library holding at least the clips of the sim's episodes: the whole one when it is built (or
    a small / folder one); else only those clips, cut from the sources with the shipped index (what
    a fresh machine's first main job does instead of building the whole library)."""
    if config.sound_library != "":
        return sound_library(config.sound_library, build=True)
    library_config = SoundLibraryConfig()
    try:
        return SoundLibrary.load(library_config)
    except CacheError:
        pass
    episodes = sim_episodes(config, partial.index_library(library_config))
    clips = sorted({clip for episode in episodes for clip in episode.source_clips})
    print(f"cutting the {len(clips)} sound clips of {len(episodes)} episodes (the whole library: "
          f"scripts/build_sound_library.py)", flush=True)
    return partial.build_partial(library_config, clips)


def episode_config(config: SimConfig) -> EpisodeConfig:
    return EpisodeConfig(task=config.task, scene_split=config.world or config.scene_split, sound_split=config.sound_split,
                         count=max(EPISODE_FILE_SIZE, config.first_episode + config.num_episodes),
                         scene_preset=config.scene_preset, min_source_distance=config.min_source_distance)


def sim_episodes(config: SimConfig, library: SoundLibrary) -> list[Episode]:
    """The episodes the simulator plays, in order (generated into the episode cache when missing)."""
    episodes = episodes_for(episode_config(config), library)
    return episodes[config.first_episode:config.first_episode + config.num_episodes]


def env_config(config: SimConfig) -> EnvConfig:
    return EnvConfig(mic_noise=config.mic_noise, camera=config.camera,
                     camera_config=CameraConfig(width=config.camera_size, height=config.camera_size),
                     acoustics=dataclasses.replace(ACOUSTICS_PRESETS[config.acoustics], head=config.head,
                                                   backend=config.acoustics_backend))
