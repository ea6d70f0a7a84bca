"""The learned controllers (policies trained by ``m2h_ros.training.ppo``) behind the controller interface.

* ``move2hear_quality`` (pi^Q, paper Sec. 4): moves to improve the separation; rewarded by the
  step-to-step decrease of the refined estimate's NMSE. Three actions (no Stop).
* ``move2hear_navigation`` (pi^N + Stop, Sec. 4 far-target): navigates to the target and stops,
  on the navigation reward. Four actions. ``move2hear_navigation:confirm`` takes its Stop only where the
  supervised Stop predictor of Gan et al.'s sound locator agrees (p >= 0.5 of standing on the target).
* ``move2hear`` (the paper's Move2Hear): near-target pi^Q throughout; far-target a walker until step
  ``switch_step`` (T^N, chosen on the validation split), then pi^Q with a fresh GRU state (as the
  original's policy switch). ``navigation_stop`` says what walks and what its Stop does (:data:`STOP_MODES`):
  ``"ends"`` (default): pi^N + Stop, whose Stop ends the episode, T^N = 100 (no switch:
  on 400 validation episodes per split pi^Q after T^N = 80 did not add, docs/design/policies.md);
  ``"masked"`` (spec ``move2hear:approach``, the original's composite): the folder's approach policy
  (no Stop, as the original's far-target composite policy), else pi^N with its Stop masked (its
  probability dropped, the rest renormalised), T^N = 80, so the episode runs to its step limit;
  ``"hands_over"`` (spec ``move2hear:handover``): pi^N + Stop, its Stop the switch to pi^Q (or T^N = 80,
  whichever comes first), the episode runs to its step limit. ``move2hear:stop`` is ``"ends"`` with T^N = 80.
  ``near_switch_step`` T > 0 (default 0): near-target, the approach policy walks until step T, then pi^Q
  (``scripts/experiments/near_switch_time.py``; near-target walkers, none shipped: docs/design/policies.md).
* ``novelty`` (Sec. 5 baselines): PPO on a count-based exploration reward 1 / sqrt(n) per visited
  node, the same network as pi^Q.
* ``av_navigator`` (Sec. 5, after Chen et al. 2020): PPO on the mixed binaural spectrogram + the
  target-class plane and RGB, with the navigation reward (+ Stop).

Gan et al. (supervised location / Stop predictors, a depth occupancy map and a planner) is in
``m2h_ros.agents.gan``: it has no policy to sample.

Checkpoints: ``checkpoint`` names a policy file (``policy.pt`` of a training run); empty means the
shipped one in ``m2h_ros/models/default/policy_<kind>.pt``. For ``move2hear`` it names a directory
holding ``policy_quality.pt`` and ``policy_navigation.pt``, and where it has one ``policy_approach.pt``
(default: the shipped ones, the approach policy among them). A missing
file is a CheckpointError that says which training command writes it. Pair a pi^Q policy with the
separator trained alongside it (``separator.pt`` beside its ``policy.pt``): f^R was trained with it.

Actions are sampled from the policy's distribution (the original evaluates sampled actions) with the
slot's per-episode generator; ``greedy=True`` takes the most likely action instead.
"""

from __future__ import annotations

from abc import abstractmethod
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch

from m2h_ros.agents.base import Controller, ControllerObservation, EpisodeStart
from m2h_ros.agents.registry import GREEDY
from m2h_ros.core.sounds.library import TARGET_CATEGORIES
from m2h_ros.core.world.episodes import STOP
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.locator import load_locator
from m2h_ros.models.policy import LoadedPolicy, load_policy, policy_inputs
from m2h_ros.paths import PACKAGE_DIR

DEFAULT_POLICY_DIR = PACKAGE_DIR / "models" / "default"
# What walks before T^N and what its Stop does (Move2Hear's ``navigation_stop``) -> the default T^N, each chosen
# on the validation split (docs/design/policies.md): "ends" pi^N + Stop, the Stop ends a far-target episode (T^N = 100:
# pi^Q never takes over); "masked" the folder's approach policy (no Stop), else pi^N with its Stop
# masked (T^N = 80, the original's, re-checked on validation); "hands_over" pi^N + Stop, its Stop the switch to
# pi^Q (T^N = 80, not swept).
DEFAULT_SWITCH_STEPS = {"ends": 100, "masked": 80, "hands_over": 80}
STOP_MODES = tuple(DEFAULT_SWITCH_STEPS)


def default_policy_path(kind: str) -> Path:
    return DEFAULT_POLICY_DIR / f"policy_{kind}.pt"


# The shipped pi^Q, pi^N and approach policy come from scripts/train_shipped.sh (their recipes); the rest from
# PPO's defaults.
SHIPPED_RECIPES = {"quality": ("scripts/train_shipped.sh quality", "runs/policy_quality/stage2/policy.pt"),
                   "navigation": ("scripts/train_shipped.sh navigation", "runs/policy_navigation/stage5/policy.pt"),
                   "approach": ("THREADS=1 scripts/train_shipped.sh approach", "runs/policy_approach/approach/policy.pt")}


def train_command(kind: str, destination: Path) -> str:
    """How to make the ``kind`` policy file at ``destination`` (the shipped folder's or another)."""
    command, trained = SHIPPED_RECIPES.get(
        kind, (f"python scripts/train_policy.py --kind {kind} --out runs/policy_{kind}", f"runs/policy_{kind}/policy.pt"))
    return f"`{command}`, then copy {trained} to {destination}"


def load_learned(kind: str, path: str | Path = "") -> LoadedPolicy:
    """The ``kind`` policy at ``path`` (empty: the shipped one); a missing file names the command."""
    path = Path(path) if str(path) else default_policy_path(kind)
    if not path.is_file():
        raise CheckpointError(f"{kind} policy checkpoint {path} not found; train it with {train_command(kind, path)}")
    return load_policy(path, policy_kind=kind)


class PolicyDriver:
    """One policy network run step by step over slots, each with its own GRU state."""

    def __init__(self, loaded: LoadedPolicy, n_slots: int) -> None:
        self.loaded, self.net = loaded, loaded.net
        self.device = self.net.actor.weight.device
        self.hidden = self.net.initial_hidden(n_slots)
        self.starts = np.ones(n_slots, bool)
        self.env_actions = loaded.config.env_actions()
        self.outputs_without_stop = np.flatnonzero(self.env_actions != STOP)
        self._columns_without_stop = torch.as_tensor(self.outputs_without_stop, device=self.device)

    def reset(self, slot: int) -> None:
        self.starts[slot] = True

    def actions(self, *, allow_stop: bool = True) -> np.ndarray:
        """The environment actions :meth:`probabilities` gives the probabilities of, in its column order."""
        return self.env_actions if allow_stop else self.env_actions[self.outputs_without_stop]

    def probabilities(self, obs: ControllerObservation, target_class: np.ndarray, rows: np.ndarray, *,
                      allow_stop: bool = True) -> np.ndarray:
        """(R, A) probabilities of :meth:`actions` for slots ``rows`` (``obs`` holds those rows); advances
        their state. ``allow_stop=False``: Stop's probability is dropped and the rest renormalised (a
        softmax over the other outputs' logits: the same numbers, without underflow to 0 / 0)."""
        inputs = policy_inputs(self.loaded.config, separated_binaural=obs.separated_binaural, monaural=obs.monaural,
                               refined=obs.refined, audio=obs.audio, target_class=target_class, rgb=obs.rgb,
                               stft_config=self.loaded.stft)
        index = torch.as_tensor(rows, device=self.device)
        with torch.inference_mode():
            out = self.net.step(inputs.to(self.device), self.hidden[index],
                                torch.as_tensor(self.starts[rows], device=self.device))
            self.hidden[index] = out.hidden
        self.starts[rows] = False
        logits = out.logits.double()
        if not allow_stop:
            logits = logits[:, self._columns_without_stop]
        return torch.softmax(logits, dim=-1).cpu().numpy()


class LearnedController(Controller):
    """Base of the learned controllers: per-slot target class, sampled or greedy actions."""

    # Before a checkpoint is loaded (what evaluate.py and the sweeps ask to pick the environment):
    # policies see RGB unless trained with --no-camera, so render it; an instance says what it has.
    uses_camera: ClassVar[bool] = True

    def __init__(self, n_slots: int, *, seed: int = 0, checkpoint: str = "", greedy: bool = False) -> None:
        super().__init__(n_slots, seed=seed)
        if not isinstance(greedy, bool):
            raise ConfigError(f"greedy={greedy!r} must be a bool")
        self.greedy = greedy
        # make_controller names it by the registry's whole spec (variant and mode): what results say ran.
        self.name = type(self).name + (GREEDY if greedy else "")
        self.target_class = np.zeros(self.n_slots, np.int64)
        self.drivers = self._drivers(checkpoint)
        self.uses_camera = any(d.loaded.config.camera for d in self.drivers)

    def model_files(self) -> list[Path]:
        return [driver.loaded.path for driver in self.drivers]

    @abstractmethod
    def _drivers(self, checkpoint: str) -> list[PolicyDriver]:
        """Load the policies this controller runs."""

    def reset(self, slot: int, start: EpisodeStart) -> None:
        super().reset(slot, start)
        if start.target_class not in TARGET_CATEGORIES:
            raise ConfigError(f"target class {start.target_class!r} is not one of {TARGET_CATEGORIES}")
        self.target_class[slot] = TARGET_CATEGORIES.index(start.target_class)
        for driver in self.drivers:
            driver.reset(slot)

    def _choose(self, driver: PolicyDriver, obs: ControllerObservation, rows: np.ndarray, *,
                allow_stop: bool = True) -> np.ndarray:
        """Environment actions of slots ``rows`` from ``driver`` (obs: all slots); ``allow_stop=False``
        chooses among the other actions, Stop's probability dropped (sampled and greedy alike)."""
        probs = driver.probabilities(obs.rows(rows), self.target_class[rows], rows, allow_stop=allow_stop)
        if self.greedy:
            picks = probs.argmax(axis=1)
        else:
            draws = np.array([self.rngs[slot].random() for slot in rows.tolist()])
            picks = np.minimum((probs.cumsum(axis=1) < draws[:, None]).sum(axis=1), probs.shape[1] - 1)
        return driver.actions(allow_stop=allow_stop)[picks]

    def _choose_in_groups(self, obs: ControllerObservation,
                          groups: tuple[tuple[PolicyDriver | None, np.ndarray, bool], ...]) -> np.ndarray:
        """Actions of all slots from (driver, rows, allow_stop) groups that partition them; an empty group's
        driver is not run (it may not be loaded)."""
        actions = np.empty(self.n_slots, np.int64)
        for driver, rows, allow_stop in groups:
            if len(rows):
                actions[rows] = self._choose(driver, obs, rows, allow_stop=allow_stop)
        return actions


class SinglePolicy(LearnedController):
    """A controller that is one trained policy of kind ``kind``."""

    kind: ClassVar[str]

    def _drivers(self, checkpoint: str) -> list[PolicyDriver]:
        return [PolicyDriver(load_learned(self.kind, checkpoint), self.n_slots)]

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        return self._choose(self.drivers[0], obs, np.arange(self.n_slots))


class Move2HearQuality(SinglePolicy):
    name, kind = "move2hear_quality", "quality"
    summary = "Move2Hear pi^Q: moves to improve the refined estimate (paper Sec. 4, near-target)"


class Move2HearNavigation(SinglePolicy):
    """pi^N + Stop. ``confirm_stop`` > 0 (spec ``move2hear_navigation:confirm``): pi^N's Stop is taken only
    where the supervised Stop predictor (the shipped sound locator's, Gan et al.'s) gives the robot at least
    that probability of standing on the target's node; elsewhere Stop's probability is dropped and the rest
    renormalised, so a Stop the two disagree on becomes a step of the walk."""

    name, kind = "move2hear_navigation", "navigation"
    summary = "Move2Hear pi^N + Stop: navigates to the target and stops (paper Sec. 4, far-target)"

    def __init__(self, n_slots: int, *, seed: int = 0, checkpoint: str = "", greedy: bool = False,
                 confirm_stop: float = 0.0) -> None:
        if isinstance(confirm_stop, bool) or not isinstance(confirm_stop, (int, float)) or not 0 <= confirm_stop < 1:
            raise ConfigError(f"confirm_stop={confirm_stop!r} must be a probability in [0, 1) (0: no check)")
        self.confirm_stop = float(confirm_stop)
        self.locator = load_locator() if self.confirm_stop else None
        super().__init__(n_slots, seed=seed, checkpoint=checkpoint, greedy=greedy)

    def model_files(self) -> list[Path]:
        return super().model_files() + ([self.locator.path] if self.locator else [])

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        if self.locator is None:
            return super()._act(obs)
        _, on_target = self.locator.predict(obs.audio, self.target_class)
        confirmed = on_target >= self.confirm_stop
        driver = self.drivers[0]
        return self._choose_in_groups(obs, ((driver, np.flatnonzero(confirmed), True),
                                            (driver, np.flatnonzero(~confirmed), False)))


class Novelty(SinglePolicy):
    name, kind = "novelty", "novelty"
    summary = "PPO on a count-based exploration reward 1/sqrt(n) per visited node (paper Sec. 5)"


class AVNavigator(SinglePolicy):
    name, kind = "av_navigator", "av_navigator"
    summary = "PPO on the mixed binaural spectrogram + class and RGB, navigation reward (paper Sec. 5)"


class Move2Hear(LearnedController):
    """The paper's Move2Hear: pi^Q near-target; far-target a walker until step ``switch_step`` (T^N), then pi^Q.

    ``navigation_stop`` (one of :data:`STOP_MODES`) picks the walker and what its Stop does: "ends" (default)
    pi^N + Stop, the Stop ending the episode; "masked" the folder's approach policy (trained without Stop, as
    the original's composite policy; the shipped folder has one), else pi^N + Stop with its Stop masked, so the
    episode runs to its step limit; "hands_over" pi^N + Stop, its Stop the switch to pi^Q. ``switch_step``
    None: the mode's validated T^N (:data:`DEFAULT_SWITCH_STEPS`). ``near_switch_step`` > 0 lets the same
    walker lead near-target episodes too.
    """

    name = "move2hear"
    summary = ("Move2Hear: pi^Q near-target; far-target pi^N + Stop (T^N = 100: no switch to pi^Q, chosen on "
               "validation) (paper Sec. 4)")

    def __init__(self, n_slots: int, *, seed: int = 0, checkpoint: str = "", greedy: bool = False,
                 switch_step: int | None = None, near_switch_step: int = 0, navigation_stop: str = "ends") -> None:
        if navigation_stop not in STOP_MODES:
            raise ConfigError(f"navigation_stop={navigation_stop!r} must be one of {', '.join(STOP_MODES)}")
        if switch_step is None:
            switch_step = DEFAULT_SWITCH_STEPS[navigation_stop]
        for name, value in (("switch_step", switch_step), ("near_switch_step", near_switch_step)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ConfigError(f"{name}={value!r} must be a non-negative int")
        self.switch_step = int(switch_step)
        self.near_switch_step = int(near_switch_step)
        self.navigation_stop = navigation_stop
        self.far = np.zeros(n_slots, bool)
        self.handed_over = np.zeros(n_slots, bool)  # navigation_stop="hands_over": pi^N stopped, pi^Q acts
        super().__init__(n_slots, seed=seed, checkpoint=checkpoint, greedy=greedy)

    def _drivers(self, checkpoint: str) -> list[PolicyDriver]:
        self.folder = Path(checkpoint) if checkpoint else DEFAULT_POLICY_DIR
        if checkpoint and not self.folder.is_dir():
            raise CheckpointError(f"move2hear takes a directory holding policy_quality.pt and policy_navigation.pt, "
                                  f"got {self.folder}")
        self.quality = self._load("quality")
        self.navigation: PolicyDriver | None = None  # loaded at the first far-target episode
        return [self.quality]

    def _load(self, kind: str) -> PolicyDriver:
        return PolicyDriver(load_learned(kind, self.folder / f"policy_{kind}.pt"), self.n_slots)

    def _navigation_kind(self) -> str:
        """The far-target policy before T^N: the folder's ``policy_approach.pt`` (trained without Stop, as the
        original's composite policy) where it has one, else pi^N + Stop with its Stop masked; the other
        ``navigation_stop`` modes need pi^N + Stop."""
        if self.navigation_stop == "masked" and (self.folder / "policy_approach.pt").is_file():
            return "approach"
        return "navigation"

    def reset(self, slot: int, start: EpisodeStart) -> None:
        self.far[slot] = start.task == "far_target"
        self.handed_over[slot] = False
        if (self.far[slot] or self.near_switch_step) and self.navigation is None:
            # Near-target runs need pi^Q only (unless near_switch_step); the walker and its file only when needed.
            self.navigation = self._load(self._navigation_kind())
            self.drivers.append(self.navigation)
        super().reset(slot, start)

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        # pi^Q's GRU state starts fresh when it first acts (reset() marks it): at the switch step (near-target
        # near_switch_step, default 0; far-target switch_step) or, handing over, at pi^N's Stop.
        navigating = (obs.step < np.where(self.far, self.switch_step, self.near_switch_step)) & ~self.handed_over
        walking = np.flatnonzero(navigating)
        actions = np.empty(self.n_slots, np.int64)
        if len(walking):
            actions[walking] = self._choose(self.navigation, obs, walking,
                                            allow_stop=self.navigation_stop != "masked")
        if self.navigation_stop == "hands_over":
            stopped = walking[actions[walking] == STOP]
            self.handed_over[stopped], navigating[stopped] = True, False
        improving = np.flatnonzero(~navigating)
        if len(improving):
            actions[improving] = self._choose(self.quality, obs, improving)
        return actions
