"""The configuration of each node, one frozen dataclass each; ``params/<node>.yaml`` holds the defaults."""

from dataclasses import dataclass

from m2h_ros.config import Config, setting

TASKS = ("near_target", "far_target")
SOUND_SPLITS = ("heard", "unheard")
SCENE_SPLITS = ("train", "val", "test")
CONTROLLERS = ("move2hear", "stand_in_place", "rotate_in_place", "random", "doa", "proximity_prior",
               "novelty", "av_navigator", "move_forward")


@dataclass(frozen=True)
class SimConfig(Config):
    task: str = setting("near_target", "episode task: start near the target (20 steps) or far (100)",
                        choices=TASKS)
    sound_split: str = setting("unheard", "sound clips: heard (training) or unheard", choices=SOUND_SPLITS)
    scene_split: str = setting("test", "scenes the episodes are drawn from", choices=SCENE_SPLITS)
    num_episodes: int = setting(5, "episodes to run before the node exits", min=1, max=100000)
    first_episode: int = setting(0, "index of the first episode in the episode file", min=0)
    step_timeout_s: float = setting(30.0, "seconds to wait for the controller's action before "
                                    "aborting the run with an error", min=0.1, max=3600.0)
    mic_noise: float = setting(0.0, "std of white noise added to each ear, relative to the "
                               "mixture's RMS", min=0.0, max=10.0)
    camera_size: int = setting(128, "width and height of the RGB and depth images", min=16, max=1024)
    seed: int = setting(0, "seed of the microphone noise", min=0)


@dataclass(frozen=True)
class SeparatorNodeConfig(Config):
    checkpoint: str = setting("", "separator checkpoint (.pt); empty: the shipped compact default")
    publish_intermediate: bool = setting(True, "also publish f^B and f^M outputs, not just f^R's")


@dataclass(frozen=True)
class ControllerConfig(Config):
    policy: str = setting("random", "which controller chooses the actions", choices=CONTROLLERS)
    checkpoint: str = setting("", "policy checkpoint for learned controllers; empty: shipped default")
    seed: int = setting(0, "seed of stochastic controllers", min=0)


@dataclass(frozen=True)
class EvaluatorConfig(Config):
    scores_file: str = setting("", "JSON file the per-episode scores are written to; empty: none")


@dataclass(frozen=True)
class RecorderConfig(Config):
    output: str = setting("", "bag directory to create; empty: runs/<date-time> under the current "
                          "directory")
    topics: tuple[str, ...] = setting((), "topics to record; empty: every topic seen on the graph")
    discovery_period_s: float = setting(0.5, "how often new topics are looked for", min=0.01,
                                        max=60.0)
    flush_period_s: float = setting(0.25, "the open MCAP chunk is written to disk at least this often, "
                                    "so a killed recorder loses at most about this much", min=0.01, max=60.0)
