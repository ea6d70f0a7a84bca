"""Episodes of the Move2Hear tasks: where the sources and the agent are, and what each source plays.

Generated from fixed seeds into versioned JSON files (``scripts/generate_episodes.py``), so every
run, node and training job sees the same episodes. Each source plays one 1 s clip at every step of
its episode, as in Move2Hear, so the separator can refine one target over time.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from m2h_ros.core.sounds.library import CATEGORIES, TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.scene import SCENE_SPLITS, Scene
from m2h_ros.core.world.worlds import canonical_spec, is_world_spec, worlds_of
from m2h_ros.errors import ConfigError, EpisodeError
from m2h_ros.paths import data_dir

EPISODES_VERSION = 1
TASKS = ("near_target", "far_target")
SOUND_SPLITS = ("heard", "unheard")
# Target category, distractor category; "any": speech or music target, any distractor.
SCENARIOS: dict[str, tuple[str, str] | None] = {
    "S-vs-S": ("speech", "speech"), "S-vs-M": ("speech", "music"),
    "S-vs-B": ("speech", "background"), "M-vs-B": ("music", "background"), "any": None}
# The seed's episode lengths: 20 steps near the target, 100 when starting far (80 in training).
DEFAULT_MAX_STEPS = {"near_target": 20, "far_target": 100}
# Same numbers as the constants of m2h_msgs/MotionCommand.
STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT = 0, 1, 2, 3
ACTION_NAMES = ("stop", "move_forward", "turn_left", "turn_right")
_PLACEMENT_TRIES = 200


@dataclass(frozen=True)
class Episode:
    episode_id: str
    scene_id: str
    scene_split: str
    scene_index: int
    scene_preset: str
    task: str
    sound_split: str
    scenario: str
    max_steps: int
    start_node: int
    start_heading: int
    source_nodes: tuple[int, ...]  # target first
    source_categories: tuple[str, ...]
    source_clips: tuple[str, ...]
    seed: int

    @property
    def target_category(self) -> str:
        return self.source_categories[0]

    @property
    def target_node(self) -> int:
        return self.source_nodes[0]

    def scene(self) -> Scene:
        return scene_at(self.scene_split, self.scene_preset, self.scene_index)


def scene_at(split: str, preset: str, index: int) -> Scene:
    """The ``index``-th scene of a split, or the world of a ``map:`` / ``mesh:`` spec (index 0); both
    memoised."""
    scenes = worlds_of(split, preset=preset)
    if not 0 <= index < len(scenes):
        raise EpisodeError(f"scene index {index} is not in split {split!r} ({len(scenes)} scenes)")
    return scenes[index]


@dataclass(frozen=True)
class EpisodeConfig:
    task: str = "near_target"
    scene_split: str = "test"
    sound_split: str = "unheard"
    scenario: str = "any"
    count: int = 1000
    seed: int = 0
    n_distractors: int = 1
    min_source_distance: float = 8.0  # metres, geodesic, between any two sources (the author's value)
    near_radius: float = 3.0  # near-target: start within this geodesic distance of the target
    far_min_distance: float = 6.0  # far-target: start at least this far (geodesic) from the target
    max_steps: int | None = None  # None: 20 near-target, 100 far-target
    scene_preset: str = "default"

    def __post_init__(self) -> None:
        if is_world_spec(self.scene_split):  # one stored form per world, whatever path named it
            object.__setattr__(self, "scene_split", canonical_spec(self.scene_split))
        checks = {"task": self.task in TASKS,
                  "scene_split": self.scene_split in SCENE_SPLITS or is_world_spec(self.scene_split),
                  "sound_split": self.sound_split in SOUND_SPLITS, "scenario": self.scenario in SCENARIOS,
                  "count": self.count >= 1, "seed": self.seed >= 0,
                  "n_distractors": 1 <= self.n_distractors <= 4,
                  "min_source_distance": self.min_source_distance >= 0,
                  "near_radius": self.near_radius >= 1, "far_min_distance": self.far_min_distance >= 1,
                  "max_steps": self.max_steps is None or self.max_steps >= 1}
        for name, ok in checks.items():
            if not ok:
                raise ConfigError(f"EpisodeConfig.{name} = {getattr(self, name)!r} is invalid")

    @property
    def steps(self) -> int:
        return self.max_steps or DEFAULT_MAX_STEPS[self.task]

    def digest(self) -> str:
        text = json.dumps(dataclasses.asdict(self), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def _categories(rng: np.random.Generator, config: EpisodeConfig) -> tuple[str, ...]:
    pair = SCENARIOS[config.scenario]
    if pair is None:
        target = TARGET_CATEGORIES[int(rng.integers(len(TARGET_CATEGORIES)))]
        others = [CATEGORIES[int(rng.integers(len(CATEGORIES)))] for _ in range(config.n_distractors)]
    else:
        target, other = pair
        others = [other] * config.n_distractors
    return (target, *others)


def _place(rng: np.random.Generator, scene: Scene, config: EpisodeConfig,
           candidates: np.ndarray | None = None) -> tuple[list[int], int] | None:
    """Source nodes (target first) at least min_source_distance apart, and a start node; sources
    only on ``candidates`` when given (any node otherwise)."""
    geodesic = scene.grid.geodesic
    allowed = np.arange(scene.grid.n_nodes) if candidates is None else np.asarray(candidates)
    for _ in range(_PLACEMENT_TRIES):
        sources = [int(allowed[rng.integers(len(allowed))])]
        for _ in range(config.n_distractors):
            free = allowed[(geodesic[sources][:, allowed] >= config.min_source_distance).all(axis=0)]
            if free.size == 0:
                break
            sources.append(int(rng.choice(free)))
        if len(sources) != config.n_distractors + 1:
            continue
        to_target = geodesic[sources[0]]
        if config.task == "near_target":
            ok = (to_target > 0) & (to_target <= config.near_radius)
        else:
            ok = to_target >= config.far_min_distance
        ok[sources] = False  # never start on a source
        if ok.any():
            return sources, int(rng.choice(np.flatnonzero(ok)))
    return None


def generate_episodes(config: EpisodeConfig, library: SoundLibrary, *, progress: bool = False
                      ) -> list[Episode]:
    """``config.count`` episodes spread round-robin over the split's scenes; deterministic by seed."""
    scenes = worlds_of(config.scene_split, preset=config.scene_preset)
    rng = np.random.default_rng([config.seed, EPISODES_VERSION])
    prefix = f"{_split_label(config.scene_split)}/{config.task}/{config.sound_split}/{config.scenario}"
    return [draw_episode(rng, config, k % len(scenes), library, episode_id=f"{prefix}/{k:06d}")
            for k in tqdm(range(config.count), desc="episodes", disable=not progress)]


def draw_episode(rng: np.random.Generator, config: EpisodeConfig, scene_index: int, library: SoundLibrary, *,
                 episode_id: str, source_candidates: np.ndarray | None = None) -> Episode:
    """One episode of ``config`` in scene ``scene_index`` of its split (``config.count`` is not used):
    source placement (on ``source_candidates`` only, when given), start pose, categories, clips and
    noise seed, all drawn from ``rng``."""
    scene = scene_at(config.scene_split, config.scene_preset, scene_index)
    placed = _place(rng, scene, config, source_candidates)
    if placed is None:
        raise EpisodeError(
            f"scene {scene.scene_id} cannot hold {config.n_distractors + 1} sources "
            f"{config.min_source_distance} m apart with a {config.task} start; lower "
            f"min_source_distance or use another split")
    sources, start = placed
    categories = _categories(rng, config)
    clips = tuple(library.sample_id(rng, category=c, split=config.sound_split) for c in categories)
    return Episode(
        episode_id=episode_id, scene_id=scene.world_id, scene_split=config.scene_split,
        scene_index=scene_index, scene_preset=config.scene_preset, task=config.task,
        sound_split=config.sound_split, scenario=config.scenario, max_steps=config.steps,
        start_node=start, start_heading=int(rng.integers(4)), source_nodes=tuple(sources),
        source_categories=categories, source_clips=clips, seed=int(rng.integers(2**31)))


def save_episodes(path: str | Path, episodes: list[Episode], *, config: EpisodeConfig,
                  library: SoundLibrary) -> Path:
    """Write atomically: version, generating config, library fingerprint, one record per episode."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    document = {"version": EPISODES_VERSION, "config": dataclasses.asdict(config),
                "library": library.fingerprint,
                "episodes": [dataclasses.asdict(e) for e in episodes]}
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(document, separators=(",", ":")))
    os.replace(tmp, path)
    return path


def load_episodes(path: str | Path, *, library: SoundLibrary | None = None) -> list[Episode]:
    """Read an episode file; with ``library``, check its clips come from that library."""
    path = Path(path)
    try:
        document = json.loads(path.read_text())
        if document["version"] != EPISODES_VERSION:
            raise EpisodeError(f"{path} is episode format v{document['version']}, this code reads "
                               f"v{EPISODES_VERSION}: regenerate it")
        episodes = [Episode(**{k: tuple(v) if isinstance(v, list) else v for k, v in record.items()})
                    for record in document["episodes"]]
    except FileNotFoundError as exc:
        raise EpisodeError(f"episode file {path} does not exist") from exc
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise EpisodeError(f"episode file {path} is corrupt: {exc}") from exc
    if library is not None and document["library"] != library.fingerprint:
        raise EpisodeError(f"{path} was generated for sound library {document['library']}, not "
                           f"{library.fingerprint}: regenerate it")
    return episodes


def _split_label(split: str) -> str:
    """A split's name in episode ids and file names: itself, or an imported world's kind, name and
    fingerprint (a changed map or mesh gets episodes of its own)."""
    if not is_world_spec(split):
        return split
    world = worlds_of(split)[0]
    return f"{world.source}-{world.scene_id}-{world.fingerprint()}"


def episode_path(config: EpisodeConfig, library: SoundLibrary) -> Path:
    name = (f"{_split_label(config.scene_split)}-{config.task}-{config.sound_split}-{config.scenario}-"
            f"{config.digest()}-{library.fingerprint}.json")
    return data_dir() / "episodes" / f"v{EPISODES_VERSION}" / name


def episodes_for(config: EpisodeConfig, library: SoundLibrary, *, progress: bool = False) -> list[Episode]:
    """The episodes of ``config``, from the cache file or generated and cached now."""
    path = episode_path(config, library)
    if path.exists():
        return load_episodes(path, library=library)
    episodes = generate_episodes(config, library, progress=progress)
    save_episodes(path, episodes, config=config, library=library)
    return episodes
