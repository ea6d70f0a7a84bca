"""Controllers by name: what ``controller_node``'s ``policy`` parameter and ``scripts/evaluate.py``
accept. Implementations are imported when made, so listing names imports nothing heavy."""

from __future__ import annotations

import importlib

from m2h_ros.agents.base import Controller
from m2h_ros.errors import ConfigError

# name -> "module:Class" of the training-free baselines (m2h_ros/agents/baselines.py).
TRAINING_FREE = {
    "stand_in_place": "m2h_ros.agents.baselines:StandInPlace",
    "rotate_in_place": "m2h_ros.agents.baselines:RotateInPlace",
    "random": "m2h_ros.agents.baselines:RandomActions",
    "move_forward": "m2h_ros.agents.baselines:MoveForward",
    "doa": "m2h_ros.agents.baselines:DirectionOfArrival",
    "proximity_prior": "m2h_ros.agents.baselines:ProximityPrior",
}
# name -> "module:Class" of the learned controllers (m2h_ros/agents/learned.py); they take ``checkpoint``.
LEARNED = {
    "move2hear": "m2h_ros.agents.learned:Move2Hear",
    "move2hear_quality": "m2h_ros.agents.learned:Move2HearQuality",
    "move2hear_navigation": "m2h_ros.agents.learned:Move2HearNavigation",
    "novelty": "m2h_ros.agents.learned:Novelty",
    "av_navigator": "m2h_ros.agents.learned:AVNavigator",
}
# name -> "module:Class" of the controllers built on supervised models (m2h_ros/agents/gan.py); they
# take ``checkpoint`` (the model's) but have no action distribution to sample or be greedy with.
SUPERVISED = {
    "gan_et_al": "m2h_ros.agents.gan:GanEtAl",
}
# "<learned name>:greedy" takes each step's most likely action instead of sampling (the original
# evaluates sampled actions); results are labelled with the whole spec.
GREEDY = ":greedy"
CONTROLLER_NAMES = (*TRAINING_FREE, *LEARNED, *SUPERVISED, *(name + GREEDY for name in LEARNED))


def controller_class(name: str) -> type[Controller]:
    base = name.removesuffix(GREEDY)
    target = TRAINING_FREE.get(name) or SUPERVISED.get(name) or (LEARNED.get(base) if base in LEARNED else None)
    if target is None:
        raise ConfigError(f"unknown controller {name!r}; available: {', '.join(CONTROLLER_NAMES)}")
    module, cls = target.split(":")
    return getattr(importlib.import_module(module), cls)


def make_controller(name: str, n_slots: int, *, seed: int = 0, checkpoint: str = "", **options) -> Controller:
    """A controller of ``n_slots`` slots; ``checkpoint`` and ``options`` (e.g. move2hear's
    ``switch_step``, gan_et_al's ``replan_every``) are for learned and supervised controllers only."""
    cls = controller_class(name)
    if name in TRAINING_FREE:
        if checkpoint or options:
            raise ConfigError(f"controller {name!r} needs no training; it takes no checkpoint or options")
        return cls(n_slots, seed=seed)
    if name not in SUPERVISED:
        options = dict(options, greedy=name.endswith(GREEDY))
    try:
        return cls(n_slots, seed=seed, checkpoint=checkpoint, **options)
    except TypeError as error:  # an option the class does not take
        raise ConfigError(f"controller {name!r}: {error}") from error
