"""DD-PPO: two torchrun workers (gloo on this CPU machine) with their own environments stay in sync."""

import csv
import dataclasses
import os
import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from m2h_ros.core.world.env import BatchEnv
from m2h_ros.core.world.episodes import episodes_for
from m2h_ros.training.ppo import PPOTrainer
from test_ppo import STEPS, tiny

HERE = Path(__file__).resolve().parent


# auto: the CPU here (gloo); on a one-GPU machine both workers share the GPU (gloo on CUDA tensors), and
# "cpu" checks a CPU run there does not reach for nccl.
@pytest.mark.parametrize("device", ["auto", "cpu"] if torch.cuda.is_available() else ["auto"])
def test_two_workers_keep_identical_weights(device, fast_env, separator_path, folder_library, tmp_path):
    # The shipped pi^Q's recipe: SI-SDR reward and the location head, whose weights must stay in sync too.
    config = tiny(fast_env, separator_path, updates=2, checkpoint_every=2, quality_reward="si_sdr", final_weight=0.0,
                  location_coef=1.0, device=device)
    config = dataclasses.replace(config, episodes=dataclasses.replace(config.episodes, count=4))
    # Episodes and RIR banks first, so the workers do not build the same cache files at once.
    env = BatchEnv(episodes_for(config.episode_config(), folder_library), folder_library, n_envs=1, config=fast_env)
    env.prepare(progress=False)
    env.close()
    (tmp_path / "config.pkl").write_bytes(pickle.dumps(config))
    torchrun = Path(sys.executable).with_name("torchrun")
    run = subprocess.run([str(torchrun), "--standalone", "--nproc_per_node", "2", str(HERE / "ddppo_worker.py"),
                          str(tmp_path / "config.pkl"), str(tmp_path / "run")],
                         capture_output=True, text=True, timeout=240, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert run.returncode == 0, run.stderr[-3000:]
    weights = [torch.load(tmp_path / "run" / f"rank{r}.pt", weights_only=True) for r in (0, 1)]
    for name, tensor in weights[0].items():
        torch.testing.assert_close(weights[1][name], tensor, rtol=0, atol=0, msg=name)
    initial = PPOTrainer(config, folder_library, out_dir=tmp_path / "unused", progress=False)
    initial.env.close()
    assert any(not torch.equal(t, initial.net.state_dict()[n]) for n, t in weights[0].items())  # it trained
    # Each worker has its own experience (its own episode order: slot 0 is on episode 3 in rank 0 and
    # on episode 2 in rank 1), and the log counts both workers' steps.
    states = [torch.load(tmp_path / "run" / f"resume.rank{r}.pt", weights_only=True) for r in (0, 1)]
    for name, tensor in states[0]["location_head"].items():
        torch.testing.assert_close(states[1]["location_head"][name], tensor, rtol=0, atol=0, msg=name)
    assert states[0]["env"]["episode_index"] != states[1]["env"]["episode_index"]
    assert not torch.equal(states[0]["obs"]["audio"], states[1]["obs"]["audio"])
    with open(tmp_path / "run" / "log.csv") as f:
        rows = list(csv.DictReader(f))
    assert int(rows[-1]["env_steps"]) == 2 * 2 * config.n_envs * STEPS
