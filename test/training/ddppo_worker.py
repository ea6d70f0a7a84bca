"""One DD-PPO worker of test_ddppo.py (started by torchrun): trains the pickled PPOConfig CONFIG on
the synthetic folder library of test/conftest.py, then saves its weights to OUT/rank<r>.pt."""

import importlib.util
import os
import pickle
import sys
from pathlib import Path

import torch

from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.training.distributed import close_distributed
from m2h_ros.training.ppo import train

spec = importlib.util.spec_from_file_location("root_conftest", Path(__file__).resolve().parents[1] / "conftest.py")
root_conftest = importlib.util.module_from_spec(spec)
spec.loader.exec_module(root_conftest)

config_path, out = Path(sys.argv[1]), Path(sys.argv[2])
rank = int(os.environ["RANK"])
folders = root_conftest.write_sound_folders(out / f"folders{rank}")
library = SoundLibrary.from_folders(folders, config=SoundLibraryConfig(clips_heard=4, clips_unheard=2))
result = train(pickle.loads(config_path.read_bytes()), library, out_dir=out, progress=False)
torch.save(result.net.state_dict(), out / f"rank{rank}.pt")
close_distributed()
