"""The batch environment and its Gymnasium wrapper on small scenes with fast acoustics."""

import dataclasses

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import rebuild_ground_truth_phase, stft
from m2h_ros.core.world.acoustics import render_binaural
from m2h_ros.core.world.camera import CameraConfig
from m2h_ros.core.world.env import BatchEnv, EnvConfig, MoveHearEnv
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT, EpisodeConfig, generate_episodes
from m2h_ros.core.world.rir_bank import RirBank, bank_dir
from m2h_ros.errors import ConfigError, M2HError

SMALL = dict(scene_preset="small", min_source_distance=3.0)


@pytest.fixture(scope="module")
def config(fast_acoustics):
    return EnvConfig(acoustics=fast_acoustics, camera_config=CameraConfig(width=32, height=24), spectrogram=True)


@pytest.fixture(scope="module")
def near_episodes(small_library):
    return generate_episodes(EpisodeConfig(count=9, seed=4, near_radius=2.0, **SMALL), small_library)


@pytest.fixture(scope="module")
def far_episodes(small_library):
    return generate_episodes(EpisodeConfig(task="far_target", count=6, seed=1, far_min_distance=3.0,
                                           max_steps=30, **SMALL), small_library)


def make_env(episodes, library, rir_cache, config, **kwargs):
    return MoveHearEnv(episodes, library, config=config, rir_cache_dir=rir_cache, **kwargs)


def actions_to(grid, node, heading, goal):
    """Turns and forward moves along a shortest path from (node, heading) to ``goal``."""
    actions = []
    path = grid.shortest_path(node, goal)
    for here, there in zip(path, path[1:]):
        wanted = next(h for h in range(4) if grid.forward[here, h] == there)
        while heading != wanted:
            actions.append(TURN_LEFT)
            heading = (heading + 1) % 4
        actions.append(MOVE_FORWARD)
    return actions


def test_config_validation():
    with pytest.raises(ConfigError, match="mic_noise"):
        EnvConfig(mic_noise=-0.1)
    with pytest.raises(ConfigError, match="camera"):
        EnvConfig(camera="yes")
    with pytest.raises(ConfigError, match="step_penalty"):
        EnvConfig(step_penalty=float("nan"))
    with pytest.raises(ConfigError, match="acoustics"):
        EnvConfig(acoustics={"rir_length": 0.5})
    with pytest.raises(ConfigError, match="seed"):
        EnvConfig(seed=-1)


def test_observation_layout_and_actions_follow_grid(near_episodes, small_library, rir_cache, config):
    env = make_env(near_episodes, small_library, rir_cache, config)
    episode = near_episodes[0]
    obs, info = env.reset(options={"episode": episode})
    assert env.observation_space.contains(obs)
    assert obs["audio"].shape == (2, 16000) and obs["spectrogram"].shape == (2, 512, 32)
    assert obs["rgb"].shape == (24, 32, 3) and obs["depth"].shape == (24, 32, 1)
    assert obs["node"] == episode.start_node and obs["heading"] == episode.start_heading
    assert obs["target_class"] == ("speech", "music").index(episode.target_category)
    np.testing.assert_array_equal(info["target_monaural"], small_library.clip(episode.source_clips[0]))
    grid = env.batch.scene_of(0).grid
    rng = np.random.default_rng(0)
    node, heading = episode.start_node, episode.start_heading
    moved = 0
    for step in range(1, 20):
        action = int(rng.choice([MOVE_FORWARD, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT, STOP]))
        obs, reward, terminated, truncated, info = env.step(action)
        if action == MOVE_FORWARD:
            moved += grid.forward[node, heading] != node
            node = grid.forward[node, heading]
        heading = {TURN_LEFT: (heading + 1) % 4, TURN_RIGHT: (heading - 1) % 4}.get(action, heading)
        assert (obs["node"], obs["heading"], obs["step"]) == (node, heading, step)
        assert not terminated  # Stop is a no-op in near-target episodes
        np.testing.assert_allclose(obs["pose"], [*grid.positions[node], heading * np.pi / 2], rtol=1e-6)
        assert info["geodesic_distance"] == grid.geodesic[node, episode.target_node]
        assert env.observation_space.contains(obs)
    assert moved >= 1


def test_reward_follows_geodesic_change_and_truncation(near_episodes, small_library, rir_cache, config):
    env = make_env(near_episodes, small_library, rir_cache, dataclasses.replace(config, camera=False))
    obs, info = env.reset(options={"episode": near_episodes[1]})
    assert "rgb" not in obs and "rgb" not in env.observation_space.spaces
    rng = np.random.default_rng(1)
    signs = set()
    for step in range(1, near_episodes[1].max_steps + 1):
        before = info["geodesic_distance"]
        obs, reward, terminated, truncated, info = env.step(int(rng.choice([1, 1, 2, 3])))
        gained = before - info["geodesic_distance"]
        assert reward == pytest.approx(0.25 * gained - 0.01, abs=1e-6)
        signs.add(np.sign(gained))
        assert truncated == (step == near_episodes[1].max_steps) and not terminated
    assert {-1.0, 1.0} <= signs
    with pytest.raises(M2HError, match="reset"):
        env.step(1)


def test_stop_ends_far_target_episodes(far_episodes, small_library, rir_cache, config):
    env = make_env(far_episodes, small_library, rir_cache, dataclasses.replace(config, camera=False))
    episode = far_episodes[0]
    obs, info = env.reset(options={"episode": episode})
    grid = env.batch.scene_of(0).grid
    for action in actions_to(grid, episode.start_node, episode.start_heading, episode.target_node):
        obs, reward, terminated, truncated, info = env.step(action)
        expected = 0.25 - 0.01 if action == MOVE_FORWARD else -0.01
        assert reward == pytest.approx(expected, abs=1e-6) and not (terminated or truncated)
    assert info["at_target"] and info["geodesic_distance"] == 0
    obs, reward, terminated, truncated, info = env.step(STOP)
    assert terminated and not truncated and info["success"]
    assert reward == pytest.approx(10.0 - 0.01, abs=1e-6)
    # Stop away from the target ends the episode without the bonus.
    env.reset(options={"episode": episode})
    obs, reward, terminated, truncated, info = env.step(STOP)
    assert terminated and not info["success"] and reward == pytest.approx(-0.01, abs=1e-6)


def test_mixture_is_mean_of_source_renders(near_episodes, small_library, rir_cache, config):
    env = make_env(near_episodes, small_library, rir_cache, config)
    episode = near_episodes[2]
    obs, info = env.reset(options={"episode": episode})
    obs, *_, info = env.step(MOVE_FORWARD)
    bank = RirBank(env.batch.scene_of(0), config.acoustics, cache_dir=rir_cache, progress=False)
    k = len(episode.source_nodes)
    rirs = bank.rirs(episode.source_nodes, [obs["node"]] * k, [obs["heading"]] * k)
    clips = np.stack([small_library.clip(c) for c in episode.source_clips])
    renders = render_binaural(clips, rirs)
    scale = np.abs(renders).max()
    np.testing.assert_allclose(obs["audio"], renders.mean(axis=0), atol=1e-5 * scale)
    np.testing.assert_allclose(info["target_binaural"], renders[0], atol=1e-5 * scale)
    assert np.abs(renders[1]).max() > 0.01 * scale   # the distractor is really in the mixture


def test_mic_noise_has_the_configured_relative_rms(near_episodes, small_library, rir_cache, config):
    clean_env = make_env(near_episodes, small_library, rir_cache, config)
    noisy_env = make_env(near_episodes, small_library, rir_cache, dataclasses.replace(config, mic_noise=0.1))
    for env in (clean_env, noisy_env):
        env.reset(options={"episode": near_episodes[3]})
    for _ in range(3):
        clean, *_ = clean_env.step(TURN_LEFT)
        noisy, *_ = noisy_env.step(TURN_LEFT)
        ratio = np.sqrt(np.mean((noisy["audio"] - clean["audio"]) ** 2) / np.mean(clean["audio"] ** 2))
        assert ratio == pytest.approx(0.1, rel=0.03)
        assert not np.array_equal(noisy["spectrogram"], clean["spectrogram"])


def test_same_seed_same_run_and_seeded_order(near_episodes, small_library, rir_cache, config):
    def run(seed):
        env = BatchEnv(near_episodes, small_library, n_envs=3, config=dataclasses.replace(config, seed=seed),
                       rir_cache_dir=rir_cache)
        obs, _ = env.reset()
        rng = np.random.default_rng(7)
        frames, order, ended = [obs], [], 0
        for _ in range(25):   # past the 20-step episodes: every slot auto-resets once
            obs, reward, terminated, truncated, info = env.step(rng.integers(4, size=3))
            frames.append(dict(obs, reward=reward))
            ended += info["done"].sum()
            if info["done"].any():
                assert (info["final_observation"]["step"][info["done"]] == 20).all()
                assert (obs["step"][info["done"]] == 0).all()
            order.append(info["episode_index"])
        assert ended == 3
        return frames, np.array(order)

    (a, order_a), (b, order_b), (_, order_c) = run(5), run(5), run(6)
    np.testing.assert_array_equal(order_a, order_b)
    for frame_a, frame_b in zip(a, b):
        for key in frame_a:
            np.testing.assert_array_equal(frame_a[key], frame_b[key])
    assert len(set(order_a[-1]) | set(order_a[0])) == 6   # slots take distinct episodes
    assert not np.array_equal(order_a, order_c)


def test_batch_equals_single_envs_without_pose_cache(near_episodes, small_library, rir_cache, config):
    config = dataclasses.replace(config, mic_noise=0.05)
    chosen = near_episodes[4:7]
    batch = BatchEnv(near_episodes, small_library, n_envs=3, config=config, rir_cache_dir=rir_cache,
                     threads=2)
    singles = [MoveHearEnv(near_episodes, small_library, config=config, rir_cache_dir=rir_cache,
                           pose_cache=0) for _ in chosen]
    batch_obs, _ = batch.reset(episodes=chosen)
    single_obs = [env.reset(options={"episode": e})[0] for env, e in zip(singles, chosen)]
    rng = np.random.default_rng(3)
    poses, revisits = set(), 0
    for _ in range(10):
        for i, obs in enumerate(single_obs):
            for key, value in obs.items():
                np.testing.assert_array_equal(batch_obs[key][i], value, err_msg=key)
            revisits += (i, int(obs["node"]), int(obs["heading"])) in poses
            poses.add((i, int(obs["node"]), int(obs["heading"])))
        actions = rng.choice([STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT], size=3)
        batch_obs, *_ = batch.step(actions)
        single_obs = [env.step(int(a))[0] for env, a in zip(singles, actions)]
    assert revisits >= 3   # the batch env served those from its pose cache


@pytest.mark.parametrize("spectra", ["cached", "stored"])
def test_rir_spectra_cached_or_stored_change_no_number(spectra, near_episodes, small_library, rir_cache, config):
    # Every slot of the first env renders every step with its RIRs transformed afresh; the second
    # serves poses from its pose cache and RIR spectra from the LRU shared by its slots (repeated
    # (source, receiver, heading) triples) or from the stored spectrum files. Both with microphone
    # noise, 2 threads and auto-reset into later episodes.
    config = dataclasses.replace(config, mic_noise=0.05)
    kwargs = dict(n_envs=4, config=config, rir_cache_dir=rir_cache, threads=2)
    plain = BatchEnv(near_episodes, small_library, pose_cache=0, rir_spectra_mib=0, **kwargs)
    option = dict(rir_spectra_mib=64) if spectra == "cached" else dict(stored_rir_spectra=True)
    fast = BatchEnv(near_episodes, small_library, **option, **kwargs)
    (obs_a, info_a), (obs_b, info_b) = plain.reset(), fast.reset()
    rng = np.random.default_rng(5)
    for _ in range(45):
        for key in obs_a:
            np.testing.assert_array_equal(obs_a[key], obs_b[key], err_msg=key)
        np.testing.assert_array_equal(info_a["target_binaural"], info_b["target_binaural"])
        actions = rng.integers(4, size=4)
        (obs_a, *_, info_a), (obs_b, *_, info_b) = plain.step(actions), fast.step(actions)
    assert (fast.rir_spectra_hit_rate > 0.05) == (spectra == "cached") and plain.rir_spectra_hit_rate == 0
    if spectra == "stored":   # the files it read are there
        assert list(bank_dir(fast.scene_of(0), config.acoustics, rir_cache).glob("spectra_*/src_*.npy"))
    assert fast.pose_cache_hit_rate > 0.3 and plain.pose_cache_hit_rate == 0
    plain.close()
    fast.close()


def test_rir_spectra_options_are_checked(near_episodes, small_library):
    with pytest.raises(ConfigError, match="rir_spectra_mib"):
        BatchEnv(near_episodes, small_library, n_envs=1, rir_spectra_mib=-1.0)
    with pytest.raises(ConfigError, match="stored_rir_spectra"):
        BatchEnv(near_episodes, small_library, n_envs=1, stored_rir_spectra=True, rir_spectra_mib=8.0)
    with pytest.raises(ConfigError, match="stored_rir_spectra"):
        BatchEnv(near_episodes, small_library, n_envs=1, stored_rir_spectra=1)


@pytest.mark.parametrize("task, speed", [("near_target", "threads"), ("far_target", "threads"),
                                         ("near_target", "processes"), ("far_target", "processes")])
def test_threads_pose_cache_and_render_processes_change_no_number_across_resets(
        task, speed, near_episodes, far_episodes, small_library, rir_cache, config):
    # Near-target slots all reset together (the no-copy path); far-target ones end on Stop at
    # different steps (partial resets). Three threads sharing the rows, or two render processes
    # beside this one (its pose caches in their shared map, with stored RIR spectra near the target
    # and RIR gathers far from it), with the pose cache reused by later episodes, against one
    # thread rendering every pose afresh, with microphone noise and without.
    episodes = near_episodes if task == "near_target" else far_episodes
    option = dict(threads=3) if speed == "threads" else dict(render_processes=2,
                                                             stored_rir_spectra=task == "near_target")
    for noise in (0.0, 0.05):
        kwargs = dict(n_envs=5, config=dataclasses.replace(config, mic_noise=noise), rir_cache_dir=rir_cache)
        plain = BatchEnv(episodes, small_library, threads=1, pose_cache=0, **kwargs)
        fast = BatchEnv(episodes, small_library, **option, **kwargs)
        (obs_a, info_a), (obs_b, info_b) = plain.reset(), fast.reset()
        rng, resets = np.random.default_rng(9), set()
        for _ in range(45):
            for a, b in ((obs_a, obs_b), (info_a, info_b)):
                assert a.keys() == b.keys()
                for key in a:
                    nested = a[key] if isinstance(a[key], dict) else {key: a[key]}
                    for name, value in nested.items():
                        other = b[key][name] if isinstance(a[key], dict) else b[key]
                        np.testing.assert_array_equal(value, other, err_msg=f"{key} {name}")
            if "final_observation" in info_b:   # the ended episodes' last observation is its own copy
                resets.add(int(info_b["done"].sum()))
                for key, value in info_b["final_observation"].items():
                    assert not np.shares_memory(value, obs_b[key]), key
            actions = rng.choice([STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT], size=5, p=[0.1, 0.4, 0.25, 0.25])
            (obs_a, *_, info_a), (obs_b, *_, info_b) = plain.step(actions), fast.step(actions)
        assert fast.pose_cache_hit_rate > 0.2
        assert (resets == {5}) if task == "near_target" else (resets - {5})
        plain.close()
        fast.close()


def test_render_processes_without_pose_cache_change_no_number(near_episodes, small_library, rir_cache, config):
    kwargs = dict(n_envs=3, config=config, rir_cache_dir=rir_cache, pose_cache=0)
    plain, fast = BatchEnv(near_episodes, small_library, **kwargs), \
        BatchEnv(near_episodes, small_library, render_processes=1, **kwargs)
    (obs_a, _), (obs_b, _) = plain.reset(), fast.reset()
    rng = np.random.default_rng(2)
    for _ in range(8):
        for key in ("audio", "spectrogram"):
            np.testing.assert_array_equal(obs_a[key], obs_b[key], err_msg=key)
        actions = rng.integers(4, size=3)
        (obs_a, *_), (obs_b, *_) = plain.step(actions), fast.step(actions)
    plain.close()
    fast.close()


@pytest.mark.parametrize("mic_noise", [0.0, 0.1])
def test_without_the_spectrogram_every_other_observation_is_the_same(near_episodes, small_library, rir_cache,
                                                                      config, mic_noise):
    with_it = dataclasses.replace(config, mic_noise=mic_noise)
    without = dataclasses.replace(with_it, spectrogram=False)
    kwargs = dict(n_envs=3, rir_cache_dir=rir_cache)
    envs = [BatchEnv(near_episodes, small_library, config=with_it, **kwargs),
            BatchEnv(near_episodes, small_library, config=without, **kwargs),
            BatchEnv(near_episodes, small_library, config=without, render_processes=int(mic_noise == 0), **kwargs)]
    observations = [env.reset()[0] for env in envs]
    rng = np.random.default_rng(3)
    for _ in range(12):   # poses repeat (pose-cache hits) and episodes end (actions include Stop)
        reference, *others = observations
        for obs in others:
            assert set(obs) == set(reference) - {"spectrogram"}
            for key, value in obs.items():
                np.testing.assert_array_equal(value, reference[key], err_msg=key)
        actions = rng.integers(4, size=3)
        observations = [env.step(actions)[0] for env in envs]
    for env in envs:
        env.close()
    gym = make_env(near_episodes, small_library, rir_cache, without)
    obs, _ = gym.reset(options={"episode": near_episodes[0]})
    assert "spectrogram" not in obs and gym.observation_space.contains(obs)


def test_render_processes_end_with_the_env_and_a_dead_one_is_named(near_episodes, small_library, rir_cache, config):
    import os
    import signal

    kwargs = dict(n_envs=2, config=config, rir_cache_dir=rir_cache)
    env = BatchEnv(near_episodes, small_library, render_processes=1, **kwargs)
    env.reset()
    (pid,) = env.render_process_ids
    env.close()
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    env = BatchEnv(near_episodes, small_library, render_processes=1, **kwargs)
    env.reset()
    os.kill(env.render_process_ids[0], signal.SIGKILL)
    with pytest.raises(M2HError, match="render process ended"):
        for _ in range(25):   # until a step has a fresh pose to hand out
            env.step(np.array([MOVE_FORWARD, TURN_LEFT]))
    env.close()
    with pytest.raises(ConfigError, match="render_processes"):
        BatchEnv(near_episodes, small_library, render_processes=-1, **kwargs)
    with pytest.raises(ConfigError, match="render_processes"):
        BatchEnv(near_episodes, small_library, render_processes=True, **kwargs)


def test_gymnasium_env_checker(near_episodes, small_library, rir_cache, config):
    check_env(make_env(near_episodes, small_library, rir_cache, config), skip_render_check=True)


def test_mixture_si_sdr_is_higher_at_the_target(near_episodes, small_library, rir_cache, config):
    env = make_env(near_episodes, small_library, rir_cache, dataclasses.replace(config, camera=False))
    at_target, far = [], []
    for episode in near_episodes[:6]:
        env.reset(options={"episode": episode})
        far_node = int(np.argmax(env.batch.scene_of(0).grid.geodesic[episode.target_node]))
        for start, scores in ((episode.target_node, at_target), (far_node, far)):
            obs, info = env.reset(options={"episode": dataclasses.replace(episode, start_node=start)})
            # Scored as the paper does: the magnitude (here the raw mixture's) with the target's phase,
            # since the waveform itself lags the dry clip by the propagation delay.
            estimate = rebuild_ground_truth_phase(np.abs(stft(obs["audio"].mean(axis=0))), info["target_monaural"])
            scores.append(si_sdr(estimate, info["target_monaural"]))
    assert np.mean(at_target) > np.mean(far) + 3.0, (at_target, far)


def test_bad_actions_and_episode_options(near_episodes, small_library, rir_cache, config):
    env = BatchEnv(near_episodes, small_library, n_envs=2, config=config, rir_cache_dir=rir_cache)
    with pytest.raises(M2HError, match="reset"):
        env.step(np.array([1, 1]))
    env.reset(episodes=[0, near_episodes[1]])
    with pytest.raises(ConfigError, match="actions"):
        env.step(np.array([1, 4]))
    with pytest.raises(ConfigError, match="episode index"):
        env.reset(episodes=[0, 99])
    assert [e.episode_id for e in env.current_episodes][:1] == [near_episodes[0].episode_id]


def test_target_delay_is_where_the_direct_sound_lands(near_episodes, small_library, rir_cache, config):
    env = make_env(near_episodes, small_library, rir_cache, dataclasses.replace(config, camera=False))
    acoustics = config.acoustics
    for episode in near_episodes[:3]:
        node, heading = episode.target_node, episode.start_heading
        _, info = env.reset(options={"episode": dataclasses.replace(episode, start_node=node)})
        # at the target's node the distance is 0, so the direct path is at the minimum distance
        expected = acoustics.min_distance / acoustics.speed_of_sound * acoustics.sample_rate
        assert info["target_delay"] == pytest.approx(expected)
        # The RIR the env convolved the target with (the render is checked against it above): the
        # direct sound is its largest arrival at the target's node and starts at the delay. (A plain
        # cross-correlation of the render with these dry clips peaks at strong early reflections,
        # 100-300 samples later, for most clips of this small reverberant scene.)
        bank = RirBank(env.batch.scene_of(0), acoustics, cache_dir=rir_cache, progress=False)
        rirs = bank.rirs([node], [node], [heading])
        np.testing.assert_allclose(info["target_binaural"], render_binaural(info["target_monaural"][None], rirs)[0],
                                   atol=1e-5 * np.abs(info["target_binaural"]).max())
        rir = rirs[0].mean(axis=0)
        onset = int(np.argmax(np.abs(rir) >= 0.5 * np.abs(rir).max()))
        assert abs(onset - info["target_delay"]) <= 2, (onset, info["target_delay"])
        _, info = env.reset(options={"episode": episode})
        grid = env.batch.scene_of(0).grid
        distance = np.linalg.norm(grid.positions[episode.target_node] - grid.positions[episode.start_node])
        assert info["target_delay"] == pytest.approx(
            max(distance, acoustics.min_distance) / acoustics.speed_of_sound * acoustics.sample_rate)


def test_state_restores_every_slot_in_a_new_env(near_episodes, small_library, rir_cache, config):
    noisy = dataclasses.replace(config, mic_noise=0.1, camera=False)
    actions = np.random.default_rng(3).integers(1, 4, size=(30, 3))
    env = BatchEnv(near_episodes, small_library, n_envs=3, config=noisy, rir_cache_dir=rir_cache)
    env.reset()
    for a in actions[:25]:  # past the first episodes' ends: the slots have moved on in the order
        env.step(a)
    state = env.state()
    twin = BatchEnv(near_episodes, small_library, n_envs=3, config=noisy, rir_cache_dir=rir_cache)
    twin.restore(state)
    assert twin.state() == state
    for a in actions[25:]:
        ours, twin_step = env.step(a), twin.step(a)
        np.testing.assert_array_equal(ours[0]["audio"], twin_step[0]["audio"])  # same noise draws too
        np.testing.assert_array_equal(ours[1], twin_step[1])
    assert [e.episode_id for e in env.current_episodes] == [e.episode_id for e in twin.current_episodes]
    env.close()
    twin.close()
    with pytest.raises(ConfigError, match="restore"):
        BatchEnv(near_episodes, small_library, n_envs=2, config=noisy, rir_cache_dir=rir_cache).restore(state)
