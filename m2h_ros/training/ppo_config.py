"""What one PPO run is: :class:`PPOConfig` (hyperparameters, the seed's coefficients by default) and the
policy kinds it trains (:data:`KINDS`). Read by ``training.ppo`` (the loop), ``training.ppo_cli`` (its flags) and
the benches; ``config.json`` of a run is :meth:`PPOConfig.to_dict`.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any

from m2h_ros.config import check_int_fields
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.core.world.scene import SCENE_SPLITS
from m2h_ros.errors import ConfigError
from m2h_ros.models.device import check_device
from m2h_ros.models.policy import PRESET_NAMES, PolicyConfig
from m2h_ros.training.rewards import QUALITY_REWARDS


@dataclass(frozen=True)
class KindSpec:
    """What a policy kind sees, may do, is rewarded for, and trains on by default."""

    inputs: str  # PolicyConfig.inputs
    stop: bool  # STOP among the actions
    reward: str  # quality | navigation | novelty
    task: str  # default training task
    entropy_coef: float  # the seed's: 0.01 for pi^Q, 0.2 otherwise
    train_refiner: bool
    # EnvConfig reward settings the kind trains with (success_reward, distance_reward, step_penalty);
    # None: EnvConfig's (the navigation reward of pi^N + Stop)
    env_reward: tuple[float, float, float] | None = None

    def env(self, **settings) -> EnvConfig:
        """The EnvConfig this kind trains in, ``settings`` (camera, ...) applied."""
        if self.env_reward is not None:
            settings.update(zip(ENV_REWARD_FIELDS, self.env_reward, strict=True))
        return EnvConfig(**settings)


ENV_REWARD_FIELDS = ("success_reward", "distance_reward", "step_penalty")


KINDS = {
    "quality": KindSpec("separation", False, "quality", "near_target", 0.01, True),
    "navigation": KindSpec("separation", True, "navigation", "far_target", 0.2, False),
    # The original's far-target policy for the composite (configs/tasks/farTarget: three actions, 80 steps;
    # its reward is the geodesic distance gained, DISTANCE_REWARD_SCALE 1.0, no slack or success term).
    "approach": KindSpec("separation", False, "navigation", "far_target", 0.2, False, env_reward=(0.0, 1.0, 0.0)),
    "novelty": KindSpec("separation", False, "novelty", "near_target", 0.2, False),
    "av_navigator": KindSpec("mixture", True, "navigation", "far_target", 0.2, False),
}
TRAIN_FAR_STEPS = 80  # the original trains far-target on 80-step episodes (100 at test)
# The scene splits named train*: each holds the one before (core/world/scene.py); val and test never train.
TRAINING_SCENE_SPLITS = tuple(name for name in SCENE_SPLITS if name.startswith("train"))


@dataclass(frozen=True)
class PPOConfig:
    """Hyperparameters of one training run (defaults: the seed's coefficients, the original's PPO)."""

    kind: str = "quality"
    preset: str = "compact"  # policy widths: paper | compact
    episodes: EpisodeConfig | None = None  # None: train scenes, heard sounds, the kind's task
    env: EnvConfig = field(default_factory=EnvConfig)
    separator: str = ""  # checkpoint; "" the shipped one (so stored configs name no machine's folders)
    n_envs: int = 16  # slots per worker
    n_steps: int = 20  # rollout length per update (the original's num_steps)
    updates: int = 1000
    ppo_epochs: int = 4
    n_minibatches: int = 1
    clip: float = 0.1
    gamma: float = 0.99
    gae_lambda: float = 0.95
    action_coef: float = 1.0
    value_coef: float = 0.5
    entropy_coef: float | None = None  # None: the kind's
    lr: float = 1e-4
    refiner_lr: float = 5e-4
    adam_eps: float = 1e-5
    max_grad_norm: float = 0.5
    linear_decay: bool = True  # lr and clip decay linearly to 0 over ``updates``
    train_refiner: bool | None = None  # None: the kind's
    refiner_epochs: int = 4  # passes of f^R's L1 over each rollout (the original: ppo_epoch)
    quality_reward: str = "nmse"  # quality: the measure whose improvement is the reward (QUALITY_REWARDS)
    final_weight: float = 10.0  # quality: + weight x the measure at the last step (-weight x NMSE for nmse)
    navigation_coef: float = 0.0  # quality: + weight x the env's navigation reward (per metre gained); 0: none
    teacher_coef: float = 0.0  # kickstarting: weight of the approach teacher's cross-entropy (decays with lr); 0: none
    location_coef: float = 0.0  # weight of the auxiliary target-location loss (training.location); 0: none
    init_policy: str = ""  # policy checkpoint whose weights the run starts from (models.policy.warm_start); "": random
    frozen_policy: bool = False  # no PPO update: an f^R-only stage (the policy acts as loaded)
    teacher_slots: int = 0  # frozen_policy: slots [0, teacher_slots) act with the approach teacher
    seed: int = 0
    threads: int = 2  # torch intra-op threads and env render threads
    checkpoint_every: int = 25  # updates
    device: str = "auto"  # auto: CUDA when present, else CPU

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"PPOConfig.kind={self.kind!r} must be one of {sorted(KINDS)}")
        if self.preset not in PRESET_NAMES:
            raise ConfigError(f"PPOConfig.preset={self.preset!r} must be one of {PRESET_NAMES}")
        if self.episodes is not None and not isinstance(self.episodes, EpisodeConfig):
            raise ConfigError("PPOConfig.episodes must be an EpisodeConfig or None")
        if not isinstance(self.env, EnvConfig):
            raise ConfigError("PPOConfig.env must be an EnvConfig")
        check_int_fields(self, (("n_envs", 1), ("n_steps", 1), ("updates", 1), ("ppo_epochs", 1), ("refiner_epochs", 1),
                                ("n_minibatches", 1), ("seed", 0), ("threads", 1), ("checkpoint_every", 1),
                                ("teacher_slots", 0)))
        if self.frozen_policy and not self.refiner_trained:
            raise ConfigError("PPOConfig.frozen_policy trains f^R alone: it needs train_refiner")
        if self.frozen_policy and (self.teacher_coef or self.location_coef):
            raise ConfigError("PPOConfig.frozen_policy has no policy loss: teacher_coef and location_coef must be 0")
        if self.teacher_slots and not self.frozen_policy:
            # PPO's ratios assume the policy chose every action
            raise ConfigError("PPOConfig.teacher_slots needs frozen_policy: PPO cannot learn from the teacher's actions")
        if self.teacher_slots > self.n_envs:
            raise ConfigError(f"PPOConfig.teacher_slots={self.teacher_slots} exceeds n_envs={self.n_envs}")
        if self.n_envs % self.n_minibatches:
            raise ConfigError(f"PPOConfig.n_minibatches={self.n_minibatches} must divide n_envs={self.n_envs}")
        for name in ("clip", "gamma", "gae_lambda", "lr", "refiner_lr", "adam_eps"):
            value = getattr(self, name)
            if not (isinstance(value, float) and 0 < value <= 1):
                raise ConfigError(f"PPOConfig.{name}={value!r} must be a float in (0, 1]")
        if self.quality_reward not in QUALITY_REWARDS:
            raise ConfigError(f"PPOConfig.quality_reward={self.quality_reward!r} must be one of {QUALITY_REWARDS}")
        for name in ("action_coef", "value_coef", "max_grad_norm", "final_weight", "navigation_coef", "teacher_coef",
                     "location_coef"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
                raise ConfigError(f"PPOConfig.{name}={value!r} must be a number >= 0")
        if self.entropy_coef is not None and not (isinstance(self.entropy_coef, float) and self.entropy_coef >= 0):
            raise ConfigError(f"PPOConfig.entropy_coef={self.entropy_coef!r} must be None or a float >= 0")
        check_device(self.device, field="PPOConfig.device")
        if self.spec.env_reward is not None:
            have = tuple(getattr(self.env, name) for name in ENV_REWARD_FIELDS)
            if have != self.spec.env_reward:
                raise ConfigError(f"PPOConfig.kind={self.kind!r} trains with EnvConfig "
                                  f"{dict(zip(ENV_REWARD_FIELDS, self.spec.env_reward, strict=True))}, got "
                                  f"{dict(zip(ENV_REWARD_FIELDS, have, strict=True))} (use KINDS[kind].env())")

    @property
    def spec(self) -> KindSpec:
        return KINDS[self.kind]

    @property
    def entropy(self) -> float:
        return self.spec.entropy_coef if self.entropy_coef is None else self.entropy_coef

    @property
    def refiner_trained(self) -> bool:
        return self.spec.train_refiner if self.train_refiner is None else self.train_refiner

    def episode_config(self) -> EpisodeConfig:
        if self.episodes is not None:
            return self.episodes
        far = self.spec.task == "far_target"
        return EpisodeConfig(task=self.spec.task, scene_split="train", sound_split="heard", count=2000,
                             seed=self.seed, max_steps=TRAIN_FAR_STEPS if far else None)

    def policy_config(self) -> PolicyConfig:
        return PolicyConfig.preset(self.preset, inputs=self.spec.inputs, stop=self.spec.stop,
                                   camera=self.env.camera)

    def to_dict(self) -> dict[str, Any]:
        """JSON-like values (what ``config.json`` holds and a resume must match)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))
