"""The approach teacher that kickstarts PPO: its path is a shortest one, its distribution says Stop or
turn on the target's node by the policy's actions, and its term in the PPO update (as the target-location
task's, training.location) moves the policy towards it on the states the rollout visited."""

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT, scene_at
from m2h_ros.core.world.navgrid import N_HEADINGS
from m2h_ros.errors import ConfigError
from m2h_ros.training.teacher_probe import ProbeData, collect_probe_data, fit_probe, ild_sign_accuracy
from m2h_ros.models.policy import ACTIONS_NO_STOP, ACTIONS_WITH_STOP
from m2h_ros.training.ppo import PPOTrainer, train
from m2h_ros.training.ppo_cli import build_parser, config_from_args
from m2h_ros.training.teacher import approach_action, teacher_probabilities
from test_ppo import tiny


@dataclasses.dataclass(frozen=True)
class _Episode:
    """What the teacher reads of an episode."""

    grid_scene: object
    target_node: int

    def scene(self):
        return self.grid_scene


def test_following_approach_action_walks_a_shortest_path_to_the_goal():
    grid = scene_at("test", "small", 0).grid
    rng = np.random.default_rng(0)
    for _ in range(50):
        start, goal = (int(n) for n in rng.integers(grid.n_nodes, size=2))
        node, heading, moves, turns = start, int(rng.integers(N_HEADINGS)), 0, 0
        while (action := approach_action(grid, node, heading, goal)) is not None:
            if action == MOVE_FORWARD:
                node, moves = int(grid.forward[node, heading]), moves + 1
            else:
                heading = (heading + (1 if action == TURN_LEFT else -1)) % N_HEADINGS
                turns += 1
            assert action in (MOVE_FORWARD, TURN_LEFT, TURN_RIGHT) and turns <= 2 * (moves + 1)
        assert node == goal and moves == grid.geodesic[start, goal]


def test_the_teacher_follows_the_path_and_stops_or_turns_on_the_target():
    scene = scene_at("test", "small", 0)
    grid = scene.grid
    rng = np.random.default_rng(1)
    nodes, headings = rng.integers(grid.n_nodes, size=40), rng.integers(N_HEADINGS, size=40)
    goals = (nodes + rng.integers(1, grid.n_nodes, size=40)) % grid.n_nodes  # elsewhere ...
    goals[:5] = nodes[:5]  # ... but for five slots already on their target's node
    episodes = [_Episode(scene, int(g)) for g in goals]
    for actions in (np.array(ACTIONS_NO_STOP), np.array(ACTIONS_WITH_STOP)):
        probabilities = teacher_probabilities(episodes, nodes, headings, actions)
        assert probabilities.shape == (40, len(actions)) and np.allclose(probabilities.sum(1), 1)
        for slot in range(5, 40):
            expected = approach_action(grid, int(nodes[slot]), int(headings[slot]), int(goals[slot]))
            assert probabilities[slot, list(actions).index(expected)] == 1
        on_target = probabilities[:5]
        if STOP in actions:
            assert (on_target[:, list(actions).index(STOP)] == 1).all()
        else:  # pi^Q has no Stop: either turn keeps it on the node
            turns = [list(actions).index(TURN_LEFT), list(actions).index(TURN_RIGHT)]
            assert (on_target[:, turns] == 0.5).all()
    with pytest.raises(ConfigError, match="both turns"):
        teacher_probabilities(episodes, nodes, headings, np.array([STOP, MOVE_FORWARD, TURN_LEFT]))


@pytest.mark.parametrize("flag", ["--teacher-coef", "--location-coef"])
def test_the_command_line_sets_an_auxiliary_loss_weight(flag):
    parser = build_parser()
    field = flag.removeprefix("--").replace("-", "_")
    assert getattr(config_from_args(parser.parse_args(["--kind", "quality"])), field) == 0.0  # plain PPO by default
    assert getattr(config_from_args(parser.parse_args(["--kind", "navigation", flag, "2"])), field) == 2.0
    with pytest.raises(ConfigError, match=field):
        config_from_args(parser.parse_args(["--kind", "quality", flag, "-1"]))


def rollout_outputs(trainer, rollout):
    """The policy's outputs over one rollout's states, as the update computes them."""
    with torch.no_grad():
        return trainer.net.evaluate(rollout.inputs.flat().to(trainer.device), trainer.hidden_start,
                                    torch.stack(rollout.starts).to(trainer.device))


def _teacher_ce(trainer, rollout) -> float:
    """Cross-entropy from the teacher to the policy on one rollout's states."""
    logits = rollout_outputs(trainer, rollout).logits
    return float(-(torch.stack(rollout.teacher).to(logits.device) * torch.log_softmax(logits, -1)).sum(-1).mean())


def _location_loss(trainer, rollout) -> float:
    """Huber loss of the location head's predictions on one rollout's states (training.location)."""
    predicted = trainer.location_head(rollout_outputs(trainer, rollout).outputs)
    return float(F.smooth_l1_loss(predicted, torch.stack(rollout.offsets).to(predicted.device)))


# term -> (kind, settings, the rollout's labels and their width, the logged loss, the loss on a rollout)
AUXILIARY_TERMS = {
    "teacher": ("navigation", {"teacher_coef": 1.0}, "teacher", 4, "teacher_ce", _teacher_ce),
    "location": ("quality", {"location_coef": 1.0, "train_refiner": False}, "offsets", 2, "location_loss",
                 _location_loss),
}


@pytest.mark.parametrize("term", sorted(AUXILIARY_TERMS))
def test_an_auxiliary_term_alone_moves_the_policy_towards_its_labels(term, fast_env, separator_path, folder_library,
                                                                      tmp_path):
    kind, settings, labels, width, logged, measure = AUXILIARY_TERMS[term]
    plain = train(tiny(fast_env, separator_path, updates=1), folder_library, out_dir=tmp_path / "plain",
                  progress=False)
    assert np.isnan(plain.history[-1][logged])  # logged only when the term takes part
    # Only this term moves the policy (PPO's terms weighted 0).
    config = tiny(fast_env, separator_path, kind=kind, action_coef=0.0, value_coef=0.0, entropy_coef=0.0, **settings)
    trainer = PPOTrainer(config, folder_library, out_dir=tmp_path / term, progress=False)
    try:
        trainer._begin()
        rollout, next_value, _ = trainer._collect()
        rows = getattr(rollout, labels)
        assert len(rows) == config.n_steps and rows[0].shape == (config.n_envs, width)
        with torch.no_grad():
            before = measure(trainer, rollout)
        losses = trainer._update_policy(rollout, next_value)
        assert losses[logged] == pytest.approx(before, rel=0.5)  # its first pass starts from `before`
        with torch.no_grad():
            assert measure(trainer, rollout) < 0.8 * before
    finally:
        trainer.env.close()


def test_the_probe_reads_the_teachers_states_and_fits_what_is_predictable(fast_env, separator_path,
                                                                          folder_library, tmp_path):
    config = tiny(fast_env, separator_path, kind="navigation", teacher_coef=1.0)
    trainer = PPOTrainer(config, folder_library, out_dir=tmp_path, progress=False)
    try:
        data = collect_probe_data(trainer, 2)
    finally:
        trainer.env.close()
    states = 2 * config.n_steps * config.n_envs
    assert data.ild.shape[0] == data.teacher.shape[0] == states and np.allclose(data.teacher.sum(1), 1)
    assert list(data.env_actions) == list(ACTIONS_WITH_STOP)

    # Constructed states: the ILD's sign says the turn, so the probe and the sign read it; noise does not.
    rng = np.random.default_rng(0)
    left = rng.random(2000) < 0.5
    ild = rng.normal(size=(2000, 8)) * 0.1 + np.where(left, 0.05, -0.05)[:, None]
    teacher = np.zeros((2000, 4), np.float32)
    teacher[np.arange(2000), np.where(left, 2, 3)] = 1  # TURN_LEFT, TURN_RIGHT columns of ACTIONS_WITH_STOP
    constructed = ProbeData(ild.astype(np.float32), teacher, np.array(ACTIONS_WITH_STOP))
    fit = fit_probe(constructed, epochs=150)
    assert fit["prior_ce"] == pytest.approx(np.log(2), abs=0.05) and fit["teacher_entropy"] == pytest.approx(0)
    assert fit["probe_ce"] < 0.5 * fit["prior_ce"]
    accuracy, turning = ild_sign_accuracy(constructed)
    assert turning == 2000 and accuracy > 0.85  # the mean of 8 rows: signal / noise 1.4, ~92%
    noise = fit_probe(ProbeData(rng.normal(size=(2000, 8)).astype(np.float32), teacher, np.array(ACTIONS_WITH_STOP)),
                      epochs=150)
    assert noise["probe_ce"] > 0.9 * noise["prior_ce"]
