"""Learned controllers behind the controller interface: registered, clear errors without checkpoints,
the same actions as the training loop's network, batch-independent sampling, and the composite switch."""

import numpy as np
import pytest
import torch

from m2h_ros.agents import learned
from m2h_ros.agents.base import Controller, ControllerObservation, EpisodeStart
from m2h_ros.agents.registry import LEARNED, controller_class, make_controller
from m2h_ros.core.sounds.library import TARGET_CATEGORIES
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.locator import DEFAULT_LOCATOR_CHECKPOINT, load_locator
from m2h_ros.models.policy import PolicyConfig, PolicyNet, policy_inputs, save_policy

SMALL = PolicyConfig(hidden=16, channels=(4, 8, 4), image_size=40)


def observation(n: int, step: int = 0, seed: int = 0) -> ControllerObservation:
    rng = np.random.default_rng(seed)
    return ControllerObservation(
        step=np.full(n, step, np.int64), pose=np.zeros((n, 3), np.float32),
        audio=rng.standard_normal((n, 2, 16000)).astype(np.float32),
        separated_binaural=rng.random((n, 2, 512, 32), dtype=np.float32) * 4,
        monaural=rng.random((n, 512, 32), dtype=np.float32), refined=rng.random((n, 512, 32), dtype=np.float32),
        rgb=rng.integers(0, 256, (n, 80, 80, 3), dtype=np.uint8), depth=rng.random((n, 80, 80), dtype=np.float32))


def start(task: str = "near_target", seed: int = 5, target: str = "music") -> EpisodeStart:
    return EpisodeStart(episode_id=f"e{seed}", task=task, target_class=target, max_steps=100, seed=seed)


def saved(path, config: PolicyConfig, kind: str, *, favour: int | None = None, seed: int = 0):
    torch.manual_seed(seed)
    net = PolicyNet(config).eval()
    if favour is not None:  # a policy that always picks network action ``favour``
        with torch.no_grad():
            net.actor.weight.zero_()
            net.actor.bias.fill_(-50.0)
            net.actor.bias[favour] = 50.0
    save_policy(path, net, policy_kind=kind)
    return net


def test_every_learned_controller_is_registered_and_names_its_training_command(tmp_path, monkeypatch):
    monkeypatch.setattr(learned, "DEFAULT_POLICY_DIR", tmp_path)
    kinds = {"move2hear_quality": "quality", "move2hear_navigation": "navigation", "novelty": "novelty",
             "av_navigator": "av_navigator", "move2hear": "quality"}
    assert set(LEARNED) == set(kinds)
    for name, kind in kinds.items():
        assert issubclass(controller_class(name), Controller) and controller_class(name).name == name
        command = (f"scripts/train_shipped.sh {kind}`," if kind in ("quality", "navigation")
                   else f"scripts/train_policy.py --kind {kind} ")
        with pytest.raises(CheckpointError, match=command):
            make_controller(name, 1)


def test_actions_are_the_networks_with_greedy_and_sampled_modes(tmp_path):
    net = saved(tmp_path / "q.pt", SMALL, "quality", seed=1)
    controller = learned.Move2HearQuality(3, checkpoint=str(tmp_path / "q.pt"), greedy=True)
    assert controller.uses_camera and controller.model_files() == [tmp_path / "q.pt"]
    for slot in range(3):
        controller.reset(slot, start(seed=slot, target=("speech", "music", "music")[slot]))
    obs = observation(3)
    actions = controller.act(obs)
    inputs = policy_inputs(SMALL, separated_binaural=obs.separated_binaural, monaural=obs.monaural,
                           refined=obs.refined, audio=obs.audio, target_class=np.array([0, 1, 1]), rgb=obs.rgb)
    with torch.no_grad():
        logits = net.step(inputs, net.initial_hidden(3), torch.ones(3, dtype=torch.bool)).logits
    np.testing.assert_array_equal(actions, SMALL.env_actions()[logits.argmax(1).numpy()])
    assert STOP not in actions

    # Sampled: an episode gets the same actions in any slot of any batch size.
    def play(n_slots: int, slot: int) -> list[int]:
        c = make_controller("move2hear_quality", n_slots, seed=4, checkpoint=str(tmp_path / "q.pt"))
        for s in range(n_slots):
            c.reset(s, start(seed=9 if s == slot else 100 + s))
        return [int(c.act(observation(n_slots, step, seed=step))[slot]) for step in range(12)]

    greedy = make_controller("move2hear_quality:greedy", 3, checkpoint=str(tmp_path / "q.pt"))
    assert greedy.greedy and greedy.name == "move2hear_quality:greedy"
    for slot in range(3):
        greedy.reset(slot, start(seed=slot, target=("speech", "music", "music")[slot]))
    np.testing.assert_array_equal(greedy.act(obs), actions)
    with pytest.raises(ConfigError, match="unknown controller 'doa:greedy'"):
        make_controller("doa:greedy", 1)

    in_batch = play(3, 2)
    assert len(set(in_batch)) > 1  # it samples, not always the mode
    alone = make_controller("move2hear_quality", 1, seed=4, checkpoint=str(tmp_path / "q.pt"))
    alone.reset(0, start(seed=9))
    assert [int(alone.act(observation(3, step, seed=step).rows(np.array([2])))[0]) for step in range(12)] == in_batch


NAVIGATION = PolicyConfig(**{**SMALL.to_dict(), "stop": True})


def test_composite_navigates_until_the_switch_step_then_improves_quality(tmp_path):
    saved(tmp_path / "policy_navigation.pt", NAVIGATION, "navigation", favour=0)  # always STOP
    saved(tmp_path / "policy_quality.pt", SMALL, "quality", favour=1)  # network action 1 = TURN_LEFT
    controller = make_controller("move2hear:stop", 2, checkpoint=str(tmp_path))  # pi^N's Stop kept, T^N = 80
    assert isinstance(controller, learned.Move2Hear) and controller.switch_step == 80
    assert controller.navigation_stop == "ends" and controller.name == "move2hear:stop"
    controller.reset(0, start("far_target"))
    controller.reset(1, start("near_target"))
    for step, expected in ((0, [STOP, TURN_LEFT]), (79, [STOP, TURN_LEFT]), (80, [TURN_LEFT, TURN_LEFT])):
        np.testing.assert_array_equal(controller.act(observation(2, step)), expected)
    default = make_controller("move2hear", 1, checkpoint=str(tmp_path))  # the same walker, no switch in 100 steps
    assert (default.navigation_stop, default.switch_step, default.name) == ("ends", 100, "move2hear")
    default.reset(0, start("far_target"))
    assert {int(default.act(observation(1, s))[0]) for s in (0, 80, 99)} == {STOP}
    with pytest.raises(ConfigError, match="'move2hear:stop' sets switch_step itself"):
        make_controller("move2hear:stop", 1, checkpoint=str(tmp_path), switch_step=3)
    early = make_controller("move2hear", 1, checkpoint=str(tmp_path), switch_step=3)
    early.reset(0, start("far_target"))
    assert [int(early.act(observation(1, s))[0]) for s in range(5)] == [STOP] * 3 + [TURN_LEFT] * 2
    with pytest.raises(CheckpointError, match="directory"):
        make_controller("move2hear", 1, checkpoint=str(tmp_path / "policy_quality.pt"))
    with pytest.raises(ConfigError, match="switch_step"):
        learned.Move2Hear(1, checkpoint=str(tmp_path), switch_step=-1)
    with pytest.raises(ConfigError, match="'move2hear_quality': .*switch_step"):
        make_controller("move2hear_quality", 1, checkpoint=str(tmp_path / "policy_quality.pt"), switch_step=3)
    with pytest.raises(ConfigError, match="'doa' needs no training"):
        make_controller("doa", 1, switch_step=3)


def test_composite_masks_pi_n_stop_unless_asked_sampled_and_greedy(tmp_path):
    saved(tmp_path / "policy_navigation.pt", NAVIGATION, "navigation", favour=0)  # STOP's probability ~1
    saved(tmp_path / "policy_quality.pt", SMALL, "quality", favour=1)  # network action 1 = TURN_LEFT
    for spec in ("move2hear:approach", "move2hear:approach:greedy"):  # no approach policy in the folder
        controller = make_controller(spec, 2, seed=3, checkpoint=str(tmp_path))
        assert controller.navigation_stop == "masked" and controller.name == spec and controller.switch_step == 80
        controller.reset(0, start("far_target", seed=1))
        controller.reset(1, start("near_target", seed=2))
        actions = np.array([controller.act(observation(2, step, seed=step)) for step in range(100)])
        assert STOP not in actions[:, 0] and set(actions[80:, 0]) == {TURN_LEFT}  # pi^Q after T^N
        assert set(actions[:, 1]) == {TURN_LEFT}  # near-target: pi^Q throughout, as before
        if spec == "move2hear:approach":  # renormalised over the other three, near-uniform: each one is drawn
            assert set(actions[:80, 0]) == {MOVE_FORWARD, TURN_LEFT, TURN_RIGHT}
    greedy_stop = make_controller("move2hear:stop:greedy", 1, checkpoint=str(tmp_path))
    assert greedy_stop.navigation_stop == "ends" and greedy_stop.greedy and greedy_stop.name == "move2hear:stop:greedy"
    greedy_stop.reset(0, start("far_target"))
    assert greedy_stop.act(observation(1)).tolist() == [STOP]
    with pytest.raises(ConfigError, match="'move2hear:approach' sets navigation_stop itself"):
        make_controller("move2hear:approach", 1, checkpoint=str(tmp_path), navigation_stop="ends")
    with pytest.raises(ConfigError, match="navigation_stop=True must be one of ends, masked, hands_over"):
        make_controller("move2hear", 1, checkpoint=str(tmp_path), navigation_stop=True)
    with pytest.raises(ConfigError, match="unknown controller 'move2hear_navigation:stop'"):
        make_controller("move2hear_navigation:stop", 1)
    with pytest.raises(ConfigError, match="'move2hear_navigation': .*navigation_stop"):
        make_controller("move2hear_navigation", 1, checkpoint=str(tmp_path / "policy_navigation.pt"),
                        navigation_stop="ends")


def test_composite_hands_over_to_pi_q_at_pi_n_stop(tmp_path):
    saved(tmp_path / "policy_navigation.pt", NAVIGATION, "navigation", seed=2)  # Stop drawn now and then
    saved(tmp_path / "policy_approach.pt", SMALL, "approach", favour=2)  # not used: hands_over needs pi^N + Stop
    saved(tmp_path / "policy_quality.pt", SMALL, "quality", favour=1)  # network action 1 = TURN_LEFT
    controller = make_controller("move2hear:handover", 3, seed=1, checkpoint=str(tmp_path), switch_step=30)
    assert controller.navigation_stop == "hands_over" and controller.name == "move2hear:handover"
    for slot in range(3):
        controller.reset(slot, start("far_target", seed=slot))
    actions = np.array([controller.act(observation(3, step, seed=step)) for step in range(40)])
    assert STOP not in actions  # the episode runs on: pi^Q acts at the step pi^N stopped
    assert controller.model_files()[1] == tmp_path / "policy_navigation.pt" and controller.handed_over.all()
    for slot in range(3):  # each slot walks as pi^N + Stop (same seeds) until that one stops, then pi^Q only
        ends = make_controller("move2hear", 1, seed=1, checkpoint=str(tmp_path), switch_step=30)
        ends.reset(0, start("far_target", seed=slot))
        walk = [int(ends.act(observation(3, step, seed=step).rows(np.array([slot])))[0]) for step in range(30)]
        stop = walk.index(STOP)  # within 30 steps: p(Stop) is about 1/4
        assert actions[:stop, slot].tolist() == walk[:stop] and set(actions[stop:, slot]) == {TURN_LEFT}


def test_masked_probabilities_are_the_others_renormalised(tmp_path):
    saved(tmp_path / "n.pt", NAVIGATION, "navigation", seed=2)
    loaded = learned.load_learned("navigation", tmp_path / "n.pt")
    full, masked = learned.PolicyDriver(loaded, 3), learned.PolicyDriver(loaded, 3)
    np.testing.assert_array_equal(masked.actions(allow_stop=False), [MOVE_FORWARD, TURN_LEFT, TURN_RIGHT])
    rows, target = np.arange(3), np.array([0, 1, 2])
    for step in range(3):  # the GRU state advances alike: the mask changes the choice, not the network
        obs = observation(3, step, seed=step)
        p_full = full.probabilities(obs, target, rows)
        p_masked = masked.probabilities(obs, target, rows, allow_stop=False)
        keep = full.actions() != STOP
        assert 0.1 < p_full[:, ~keep].min() and p_masked.shape == (3, 3)  # Stop had real weight
        np.testing.assert_allclose(p_masked, p_full[:, keep] / p_full[:, keep].sum(1, keepdims=True), rtol=1e-12)
        np.testing.assert_allclose(p_masked.sum(1), 1.0, rtol=1e-12)


def test_composite_needs_pi_n_only_for_far_target_episodes(tmp_path):
    saved(tmp_path / "policy_quality.pt", SMALL, "quality", favour=1)  # network action 1 = TURN_LEFT
    controller = make_controller("move2hear", 1, checkpoint=str(tmp_path))  # no policy_navigation.pt
    controller.reset(0, start("near_target"))
    assert controller.act(observation(1)).tolist() == [TURN_LEFT]
    missing = tmp_path / "policy_navigation.pt"
    with pytest.raises(CheckpointError) as error:
        controller.reset(0, start("far_target"))
    # The command in backticks, and the copy goes to the folder that lacks the file, not the shipped folder.
    assert str(error.value) == (f"navigation policy checkpoint {missing} not found; train it with "
                                "`scripts/train_shipped.sh navigation`, then copy runs/policy_navigation/stage5/policy.pt "
                                f"to {missing}")


def test_composite_walks_with_an_approach_policy_where_the_folder_has_one(tmp_path):
    saved(tmp_path / "policy_navigation.pt", NAVIGATION, "navigation", favour=0)  # always STOP
    saved(tmp_path / "policy_approach.pt", SMALL, "approach", favour=2)  # network action 2 = TURN_RIGHT
    saved(tmp_path / "policy_quality.pt", SMALL, "quality", favour=1)  # network action 1 = TURN_LEFT
    controller = make_controller("move2hear:approach", 1, checkpoint=str(tmp_path))
    controller.reset(0, start("far_target"))
    assert [int(controller.act(observation(1, s))[0]) for s in (0, 79, 80)] == [TURN_RIGHT, TURN_RIGHT, TURN_LEFT]
    assert controller.model_files() == [tmp_path / "policy_quality.pt", tmp_path / "policy_approach.pt"]
    keeps_stop = make_controller("move2hear", 1, checkpoint=str(tmp_path))  # needs pi^N + Stop
    keeps_stop.reset(0, start("far_target"))
    assert keeps_stop.act(observation(1)).tolist() == [STOP]
    (tmp_path / "policy_navigation.pt").rename(tmp_path / "policy_approach.pt")  # a pi^N + Stop file misnamed
    with pytest.raises(CheckpointError, match="holds a 'navigation' policy, expected 'approach'"):
        make_controller("move2hear:approach", 1, checkpoint=str(tmp_path)).reset(0, start("far_target"))


def test_near_target_composite_walks_with_the_approach_policy_until_its_own_switch_step(tmp_path):
    saved(tmp_path / "policy_approach.pt", SMALL, "approach", favour=2)  # network action 2 = TURN_RIGHT
    saved(tmp_path / "policy_quality.pt", SMALL, "quality", favour=1)  # network action 1 = TURN_LEFT
    controller = make_controller("move2hear:approach", 2, checkpoint=str(tmp_path), switch_step=6, near_switch_step=3)
    controller.reset(0, start("near_target"))
    controller.reset(1, start("far_target"))
    actions = [controller.act(observation(2, s)).tolist() for s in range(8)]
    assert [a[0] for a in actions] == [TURN_RIGHT] * 3 + [TURN_LEFT] * 5  # near-target: T = 3
    assert [a[1] for a in actions] == [TURN_RIGHT] * 6 + [TURN_LEFT] * 2  # far-target: T^N = 6
    with pytest.raises(ConfigError, match="near_switch_step=-2 must be a non-negative int"):
        make_controller("move2hear", 1, checkpoint=str(tmp_path), near_switch_step=-2)


def test_the_shipped_move2hear_walks_with_pi_n_and_stop_and_the_approach_variant_with_the_approach_policy():
    default = learned.DEFAULT_POLICY_DIR
    controller = make_controller("move2hear", 1)
    controller.reset(0, start("far_target"))
    assert controller.model_files() == [default / "policy_quality.pt", default / "policy_navigation.pt"]
    assert controller.navigation.loaded.config.stop and controller.switch_step == 100
    approach = make_controller("move2hear:approach", 1)
    approach.reset(0, start("far_target"))
    assert approach.model_files() == [default / "policy_quality.pt", default / "policy_approach.pt"]
    assert approach.navigation.loaded.policy_kind == "approach" and not approach.navigation.loaded.config.stop


def test_av_navigator_reads_the_mixture_and_the_target_class(tmp_path):
    config = PolicyConfig(inputs="mixture", stop=True, camera=False, hidden=16, channels=(4, 8, 4))
    saved(tmp_path / "av.pt", config, "av_navigator", favour=1)  # network action 1 = MOVE_FORWARD
    controller = make_controller("av_navigator", 1, checkpoint=str(tmp_path / "av.pt"))
    assert not controller.uses_camera
    controller.reset(0, start("far_target"))
    assert controller.act(observation(1)).tolist() == [MOVE_FORWARD]
    with pytest.raises(CheckpointError, match="'av_navigator' policy, expected 'quality'"):
        make_controller("move2hear_quality", 1, checkpoint=str(tmp_path / "av.pt"))


def test_confirmed_stop_is_taken_only_where_the_supervised_stop_predictor_agrees(tmp_path):
    saved(tmp_path / "nav.pt", NAVIGATION, "navigation", favour=0)  # pi^N: Stop's probability ~1
    checkpoint = str(tmp_path / "nav.pt")
    controller = make_controller("move2hear_navigation:confirm", 4, seed=3, checkpoint=checkpoint)
    assert controller.name == "move2hear_navigation:confirm" and controller.confirm_stop == 0.5
    assert controller.model_files() == [tmp_path / "nav.pt", DEFAULT_LOCATOR_CHECKPOINT]
    targets = ("speech", "music", "music", "speech")
    for slot in range(4):
        controller.reset(slot, start("far_target", seed=slot, target=targets[slot]))
    class_index = np.array([TARGET_CATEGORIES.index(t) for t in targets])
    agreed = []
    for step in range(8):
        obs = observation(4, step, seed=step)
        obs.audio[1] *= 30  # louder and quieter mixtures: the shipped locator's answers differ between slots
        obs.audio[2] *= 0.01
        _, on_target = load_locator().predict(obs.audio, class_index)
        actions = controller.act(obs)
        np.testing.assert_array_equal(actions == STOP, on_target >= 0.5)
        agreed.extend(on_target >= 0.5)
    assert 0 < sum(agreed) < len(agreed)  # both branches ran
    plain = make_controller("move2hear_navigation", 1, checkpoint=checkpoint)
    plain.reset(0, start("far_target"))
    assert plain.act(observation(1)).tolist() == [STOP] and plain.model_files() == [tmp_path / "nav.pt"]
    with pytest.raises(ConfigError, match="confirm_stop=1.5 must be a probability"):
        make_controller("move2hear_navigation", 1, checkpoint=checkpoint, confirm_stop=1.5)
    with pytest.raises(ConfigError, match="sets confirm_stop itself"):
        make_controller("move2hear_navigation:confirm", 1, checkpoint=checkpoint, confirm_stop=0.7)
