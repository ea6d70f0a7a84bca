"""The QoS depths hold what the lockstep lets a lagging reader fall behind by."""

import dataclasses

import pytest

from m2h_ros.core.world.episodes import DEFAULT_MAX_STEPS
from m2h_ros.node_configs import SimConfig
from m2h_ros.ros.qos import LATCHED, STEP

pytestmark = pytest.mark.graph


def largest_lag() -> int:
    return next(f for f in dataclasses.fields(SimConfig) if f.name == "max_evaluator_lag").metadata["max"]


def test_step_history_holds_the_largest_evaluator_lag():
    assert STEP.depth > largest_lag()


def test_episode_infos_of_every_episode_the_sim_may_run_ahead_are_kept():
    shortest_episode = min(DEFAULT_MAX_STEPS.values()) + 1  # observations
    assert LATCHED.depth >= -(-largest_lag() // shortest_episode) + 1
