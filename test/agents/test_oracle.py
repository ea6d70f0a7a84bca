"""The privileged approach oracle (a diagnostic, not a baseline): it follows a shortest path to the
target's node and then holds there, standing or turning, and the controller registry does not hold it;
its walks and a random one's, replayed from their actions on the grid (experiments/reach.py), end where
the environment took them."""

import dataclasses

import numpy as np
import pytest
from test_baselines import play

from m2h_ros.agents.base import EpisodeStart
from m2h_ros.agents.baselines import RandomActions
from m2h_ros.agents.registry import CONTROLLER_NAMES
from m2h_ros.core.results import EpisodeResult
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT
from m2h_ros.errors import ConfigError
from m2h_ros.experiments.oracle import ApproachOracle
from m2h_ros.experiments.reach import REACH_GROUPS, gain_by_reach, geodesic_trace, plot_reach, reach_table


def test_the_oracle_reaches_the_target_node_and_holds_there(folder_library, env_config, small_episodes):
    episodes = small_episodes(count=6, max_steps=10)
    record, grids = play(ApproachOracle(len(episodes), episodes=episodes), episodes, folder_library, env_config)
    targets = np.array([e.target_node for e in episodes])
    assert (record["node"][-1] == targets).all()
    arrived = record["node"][:-1] == targets  # (steps, slots): on the target's node before acting
    assert (record["action"][arrived] == STOP).all()  # near-target hold: Stop, a no-op
    assert (record["action"][~arrived] != STOP).all()
    walked = (record["action"] == MOVE_FORWARD).sum(0)
    assert (walked == [grid.geodesic[e.start_node, e.target_node] for grid, e in zip(grids, episodes)]).all()


def test_the_turning_oracle_walks_the_same_path_then_turns_on_the_node(folder_library, env_config, small_episodes):
    episodes = small_episodes(count=6, max_steps=10)
    standing, _ = play(ApproachOracle(len(episodes), episodes=episodes), episodes, folder_library, env_config)
    oracle = ApproachOracle(len(episodes), episodes=episodes, hold="turn")
    assert oracle.name == "approach_oracle_turning"
    turning, _ = play(oracle, episodes, folder_library, env_config)
    targets = np.array([e.target_node for e in episodes])
    arrived = turning["node"][:-1] == targets
    assert arrived.any() and (turning["action"][arrived] == TURN_LEFT).all()
    np.testing.assert_array_equal(turning["action"][~arrived], standing["action"][~arrived])
    assert (turning["node"] == standing["node"]).all()  # turning on the node keeps it there
    with pytest.raises(ConfigError, match="hold='sit'"):
        ApproachOracle(1, episodes=episodes, hold="sit")


def test_the_oracle_is_no_registered_controller_and_knows_only_its_episodes(small_episodes):
    assert ApproachOracle.name not in CONTROLLER_NAMES  # the controller node and evaluate.py cannot run it
    oracle = ApproachOracle(1, episodes=small_episodes(count=1, max_steps=3))
    with pytest.raises(ConfigError, match="not in the list"):
        oracle.reset(0, EpisodeStart("elsewhere", "near_target", "speech", 3, 0))


def test_replayed_walks_end_where_the_environment_took_them(folder_library, env_config, small_episodes, tmp_path):
    episodes = small_episodes(count=6, max_steps=10)
    by_id, rows = {e.episode_id: e for e in episodes}, []
    for controller in (ApproachOracle(len(episodes), episodes=episodes), RandomActions(len(episodes), seed=1)):
        record, grids = play(controller, episodes, folder_library, env_config)
        for slot, (episode, grid) in enumerate(zip(episodes, grids, strict=True)):
            trace = geodesic_trace(episode, record["action"][:, slot].tolist())
            np.testing.assert_array_equal(trace, grid.geodesic[record["node"][:, slot], episode.target_node])
            rows.append(EpisodeResult(episode.episode_id, controller.name, "near_target", "heard", episode.scene_id,
                                      "speech", actions=record["action"][:, slot].tolist(), si_sdr=[0.0, slot + 1.0],
                                      shortest_path=float(trace[0])))
    standing = [EpisodeResult(e.episode_id, "stand_in_place", "near_target", "heard", e.scene_id, "speech",
                              si_sdr=[0.0, 0.5], shortest_path=rows[i].shortest_path) for i, e in enumerate(episodes)]
    oracle, random = reach_table(rows, by_id)
    assert (oracle.controller, oracle.final_m, oracle.ends_on_target, oracle.ever_on_target) == \
        ("approach_oracle", 0.0, 1.0, 1.0)
    assert random.controller == "random" and random.start_m == oracle.start_m > 0
    stopped = dataclasses.replace(rows[-1], actions=rows[-1].actions[:1])  # a walk that ended after one step
    assert reach_table([stopped, rows[-2]], by_id)[0].episodes == 2  # episodes of unequal length summarise
    assert plot_reach(rows, by_id, tmp_path / "reach.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    gains = gain_by_reach(rows + standing, by_id, reference="stand_in_place")
    assert gains[0] == ("approach_oracle", "", "near_target", "heard", REACH_GROUPS[0], 6, np.mean(np.arange(1, 7)) - 0.5)
    assert sum(g[5] for g in gains[1:]) == 6 and {g[0] for g in gains[1:]} == {"random"}
    with pytest.raises(ConfigError, match="played .*000000.*, stand_in_place did not"):
        gain_by_reach(rows + standing[1:], by_id, reference="stand_in_place")
    swept = [dataclasses.replace(r, condition="T = 3") for r in rows]  # a sweep's conditions, one plain reference
    assert [g[1:] for g in gain_by_reach(swept + standing, by_id, reference="stand_in_place")] == \
        [("T = 3", *g[2:]) for g in gains]
    with pytest.raises(ConfigError, match="stand_in_place did not"):  # a reference of another condition is not it
        gain_by_reach(swept + [dataclasses.replace(r, condition="T = 5") for r in standing], by_id,
                      reference="stand_in_place")
    moved = dataclasses.replace(rows[0], shortest_path=rows[0].shortest_path + 1)  # another episode behind the id
    with pytest.raises(ConfigError, match="not among the episodes given"):
        reach_table([moved], by_id)
