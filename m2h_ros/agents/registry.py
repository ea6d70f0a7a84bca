"""Controllers by name: what ``controller_node``'s ``policy`` parameter and ``scripts/evaluate.py``
accept. Implementations are imported when made, so listing names imports nothing heavy.

Other packages add controllers without editing this one: an entry point in the group
``m2h_ros.controllers`` (``name = "module:Class"``, a :class:`Controller` subclass) makes ``name`` a
controller of the node, of the launch file and of ``scripts/evaluate.py``
(docs/how-to/add-a-controller.md)."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from importlib.metadata import entry_points

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


@dataclass(frozen=True)
class Variant:
    """A registry spec that is a learned controller with some keyword options set."""

    name: str  # the learned controller (a LEARNED key)
    options: dict
    summary: str


# Plain "move2hear" walks far-target with pi^N + Stop, whose Stop ends the episode, to step 100 (T^N chosen on
# validation). "move2hear:approach" is the composite as the original trains it (an approach policy
# without Stop, pi^Q from T^N = 80); "move2hear:stop" pi^N + Stop until T^N = 80,
# then pi^Q; "move2hear:handover" pi^N + Stop whose Stop is the switch to pi^Q (docs/design/policies.md).
APPROACH = ":approach"
NAVIGATION_STOP = ":stop"
HAND_OVER = ":handover"
# "move2hear_navigation:confirm": pi^N + Stop whose Stop needs the supervised Stop predictor's agreement
# (Gan et al.'s sound locator, p >= 0.5; chosen on the validation split, docs/design/policies.md).
CONFIRM_STOP = ":confirm"
LEARNED_VARIANTS = {
    "move2hear" + APPROACH: Variant("move2hear", {"navigation_stop": "masked"},
                                    "Move2Hear walking far-target with the approach policy (no Stop), then pi^Q "
                                    "from T^N = 80 (the original's composite)"),
    "move2hear" + NAVIGATION_STOP: Variant("move2hear", {"navigation_stop": "ends", "switch_step": 80},
                                           "Move2Hear walking with pi^N + Stop until T^N = 80, then pi^Q"),
    "move2hear" + HAND_OVER: Variant("move2hear", {"navigation_stop": "hands_over"},
                                     "Move2Hear walking with pi^N + Stop, its Stop the switch to pi^Q (or T^N)"),
    "move2hear_navigation" + CONFIRM_STOP: Variant(
        "move2hear_navigation", {"confirm_stop": 0.5},
        "pi^N + Stop, its Stop taken only where Gan et al.'s supervised Stop predictor agrees (p >= 0.5)"),
}
# "<learned spec>:greedy" takes each step's most likely action instead of sampling (the original
# evaluates sampled actions); results are labelled with the whole spec.
GREEDY = ":greedy"
LEARNED_SPECS = (*LEARNED, *LEARNED_VARIANTS)
BUILT_IN_NAMES = (*TRAINING_FREE, *LEARNED_SPECS, *SUPERVISED, *(spec + GREEDY for spec in LEARNED_SPECS))
PLUGIN_GROUP = "m2h_ros.controllers"


def _plugins() -> dict[str, str]:
    """name -> "module:Class" of the controllers installed packages register under PLUGIN_GROUP. Reads
    package metadata only; a plugin's module is imported when its controller is made."""
    found: dict[str, str] = {}
    for entry in entry_points(group=PLUGIN_GROUP):
        where = f"entry point {entry.name!r} of {entry.dist.name if entry.dist else 'an unknown package'}"
        if entry.name in BUILT_IN_NAMES or entry.name in found:
            raise ConfigError(f"{where} in {PLUGIN_GROUP} reuses the controller name {entry.name!r}; choose another")
        if ":" in entry.name or ":" not in entry.value:
            raise ConfigError(f"{where} in {PLUGIN_GROUP} must read NAME = \"module:Class\" with no ':' in NAME, "
                              f"got {entry.name} = {entry.value!r}")
        found[entry.name] = entry.value
    return found


# Read once per process, at import: the node's parameter choices and the launch file see the same set.
PLUGINS = _plugins()
CONTROLLER_NAMES = (*BUILT_IN_NAMES, *PLUGINS)


def _learned_spec(spec: str) -> tuple[str, dict] | None:
    """(learned name, options) a learned controller's spec stands for; None if it is not one."""
    base = spec.removesuffix(GREEDY)
    variant = LEARNED_VARIANTS.get(base, Variant(base, {}, ""))
    if variant.name not in LEARNED:
        return None
    return variant.name, {**variant.options, "greedy": spec.endswith(GREEDY)}


def is_learned(name: str) -> bool:
    """Whether ``name`` is a learned controller's spec (it takes a policy checkpoint and options)."""
    return _learned_spec(name) is not None


def controller_class(name: str) -> type[Controller]:
    learned = _learned_spec(name)
    target = (TRAINING_FREE.get(name) or SUPERVISED.get(name) or PLUGINS.get(name)
              or (LEARNED[learned[0]] if learned else None))
    if target is None:
        raise ConfigError(f"unknown controller {name!r}; available: {', '.join(CONTROLLER_NAMES)}")
    module, _, attribute = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as error:
        raise ConfigError(f"controller {name!r}: cannot load {target!r} ({error})") from error
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        raise ConfigError(f"controller {name!r}: {target!r} is not a subclass of m2h_ros.agents.base.Controller")
    return cls


def make_controller(name: str, n_slots: int, *, seed: int = 0, checkpoint: str = "", **options) -> Controller:
    """A controller of ``n_slots`` slots; ``checkpoint`` and ``options`` (e.g. move2hear's
    ``switch_step`` and ``navigation_stop``, gan_et_al's ``replan_every``) are for learned and
    supervised controllers only; a spec's own options (``:greedy``, ``:stop``'s switch_step) cannot be passed again."""
    cls = controller_class(name)
    if name in TRAINING_FREE:
        if checkpoint or options:
            raise ConfigError(f"controller {name!r} needs no training; it takes no checkpoint or options")
        return cls(n_slots, seed=seed)
    learned = _learned_spec(name)
    if learned:
        clash = sorted(set(options) & set(learned[1]))
        if clash:
            raise ConfigError(f"controller {name!r} sets {', '.join(clash)} itself; do not pass it as an option")
        options = {**options, **learned[1]}
    # A plugin gets ``checkpoint`` only when one is set, so one that loads no model need not take it.
    given = {**options, "checkpoint": checkpoint} if checkpoint or name not in PLUGINS else options
    try:
        controller = cls(n_slots, seed=seed, **given)
    except TypeError as error:  # an option the class does not take
        raise ConfigError(f"controller {name!r}: {error}") from error
    if learned:
        controller.name = name  # the whole spec (variant, :greedy): what results say ran
    return controller
