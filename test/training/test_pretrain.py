"""Separator pretraining on tiny streams: losses fall, the checkpoint rebuilds itself, a resumed run
equals an uninterrupted one, the refiner respects episode boundaries, and passive evaluation scores
floor, separator and oracle with the shared scoring."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.results import METRICS
from m2h_ros.core.world.env import BatchEnv
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.checkpoint import load_separator
from m2h_ros.models.separator import Separator, SeparatorConfig
from m2h_ros.training.passive_eval import ESTIMATES, evaluate_passive, gap_closed, summarize
from m2h_ros.training.pretrain_separator import (
    PretrainConfig,
    _refine_sequences,
    build_parser,
    config_from_args,
    pretrain,
    state_path,
)

TINY = SeparatorConfig(unet_channels=(8, 8, 16, 16, 16), refiner_hidden=8)


@pytest.fixture(scope="module")
def config(small_stream, small_sequences, small_val_stream):
    return PretrainConfig(model=TINY, lr=3e-3, epochs=3, batches_per_epoch=8, refiner_epochs=2,
                          refiner_batches_per_epoch=2, train_data=small_stream, refiner_data=small_sequences,
                          val_data=small_val_stream, val_batches=2, threads=1, workers=0)


@pytest.fixture(scope="module")
def trained(config, folder_library, tmp_path_factory, training_data_dir):
    out = tmp_path_factory.mktemp("ckpt") / "sep.pt"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("M2H_DATA_DIR", str(training_data_dir))
        return pretrain(config, folder_library, out=out, progress=False, command="test", on_epoch=lambda *_: None)


def test_training_lowers_the_loss_and_keeps_the_best_epoch(trained):
    stage1, stage2 = trained.metadata["history"]["stage1"], trained.metadata["history"]["stage2"]
    assert [h["epoch"] for h in stage1] == [1, 2, 3] and len(stage2) == 2
    # Every batch is new data: the fixed validation set shows the progress.
    assert stage1[-1]["val_binaural_l1"] < stage1[0]["val_binaural_l1"]
    assert stage1[-1]["val_monaural_l1"] < stage1[0]["val_monaural_l1"]
    final = trained.metadata["final"]
    assert all(np.isfinite(v) for v in final.values())
    assert final["val_monaural_l1"] == min(h["val_monaural_l1"] for h in stage1)
    assert final["val_refined_l1"] == min(h["val_refined_l1"] for h in stage2)
    # The references of f^B do not depend on the weights; the ideal mask bounds the identity mask.
    assert len({h["val_identity_mask_binaural_l1"] for h in stage1}) == 1
    assert final["val_ideal_mask_binaural_l1"] < final["val_identity_mask_binaural_l1"]
    assert trained.metadata["observations_seen"] == {"stage1": 3 * 8 * 4, "stage2": 2 * 2 * 3 * 3}


def test_checkpoint_rebuilds_with_classes_and_metadata(trained):
    loaded = load_separator(trained.checkpoint, expected_config=TINY, expected_classes=("speech", "music"))
    meta = loaded.metadata
    assert meta["mixture_power"] > 0 and meta["command"] == "test" and meta["resumed_from"] is None
    assert meta["validation"] == {"sequences": 6, "steps": 3} and meta["machine"]["cpu_count"] >= 1
    assert torch.device(meta["machine"]["device"]).type == ("cuda" if torch.cuda.is_available() else "cpu")  # "auto"
    side = json.loads(trained.checkpoint.with_suffix(".json").read_text())
    assert side["final"] == meta["final"]
    assert trained.checkpoint.with_name("sep_loss.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not state_path(trained.checkpoint).exists()  # removed once the run completed
    mixture = torch.rand(3, 32, 32, 32) * 20
    classes = torch.tensor([0, 1, 0])
    with torch.no_grad():
        expected = trained.separator.eval()(mixture, classes).refined
        np.testing.assert_allclose(loaded.separator(mixture, classes).refined, expected, rtol=1e-5, atol=1e-5)


class Interrupt(Exception):
    pass


@pytest.mark.parametrize("stop_at", [("stage1", 1), ("stage2", 1)])
def test_a_resumed_run_equals_an_uninterrupted_one(stop_at, trained, config, folder_library, tmp_path):
    out = tmp_path / "sep.pt"

    def interrupt(stage, record):
        if (stage, record["epoch"]) == stop_at:
            raise Interrupt

    with pytest.raises(Interrupt):
        pretrain(config, folder_library, out=out, progress=False, on_epoch=interrupt)
    assert state_path(out).exists() and not out.exists()
    resumed = pretrain(dataclasses.replace(config, workers=2), folder_library, out=out, progress=False,
                       on_epoch=lambda *_: None)
    assert resumed.metadata["resumed_from"] == {"stage": stop_at[0], "epoch": stop_at[1]}
    for stage in ("stage1", "stage2"):
        got, expected = resumed.metadata["history"][stage], trained.metadata["history"][stage]
        assert len(got) == len(expected)
        for a, b in zip(got, expected):
            assert a.keys() == b.keys()
            np.testing.assert_allclose([a[k] for k in a], [b[k] for k in a], rtol=1e-5, err_msg=stage)


def test_a_state_of_another_configuration_is_refused(config, folder_library, tmp_path):
    out = tmp_path / "sep.pt"
    with pytest.raises(Interrupt):
        pretrain(config, folder_library, out=out, progress=False,
                 on_epoch=lambda *_: (_ for _ in ()).throw(Interrupt))
    with pytest.raises(CheckpointError, match="another configuration"):
        pretrain(dataclasses.replace(config, lr=1e-3), folder_library, out=out, progress=False)
    # Other epoch counts are the same run, stopped elsewhere: a stage-1 state continues with them.
    cut = pretrain(dataclasses.replace(config, epochs=1, refiner_epochs=1), folder_library, out=out,
                   progress=False, on_epoch=lambda *_: None)
    assert cut.metadata["resumed_from"] == {"stage": "stage1", "epoch": 1}
    assert cut.metadata["epochs_run"] == {"stage1": 1, "stage2": 1}
    # --fresh ignores a state (and then replaces it).
    with pytest.raises(Interrupt):
        pretrain(config, folder_library, out=out, progress=False,
                 on_epoch=lambda *_: (_ for _ in ()).throw(Interrupt))
    result = pretrain(dataclasses.replace(config, epochs=1, refiner_epochs=1), folder_library, out=out,
                      progress=False, fresh=True, on_epoch=lambda *_: None)
    assert result.metadata["resumed_from"] is None and not state_path(out).exists()


def test_cosine_schedule_runs_from_lr_to_final_lr_and_fixes_the_epoch_count(config):
    assert config.stage1_lr(0) == config.stage1_lr(10**6) == config.lr  # constant by default
    annealed = dataclasses.replace(config, final_lr=1e-4)
    last = annealed.epochs * annealed.batches_per_epoch - 1
    rates = [annealed.stage1_lr(i) for i in range(last + 1)]
    assert rates[0] == pytest.approx(annealed.lr) and rates[-1] == pytest.approx(1e-4)
    assert all(a >= b for a, b in zip(rates, rates[1:]))
    # The schedule depends on the epoch count, so a resumed run must keep it.
    assert "epochs" not in config.result_fields() and "epochs" in annealed.result_fields()
    with pytest.raises(ConfigError, match="final_lr"):
        dataclasses.replace(config, final_lr=1.0)


def test_init_from_starts_stage_1_at_a_checkpoints_weights(trained, config, folder_library, tmp_path):
    tuned = dataclasses.replace(config, init_from=str(trained.checkpoint), final_lr=1e-4, epochs=1,
                                refiner_epochs=1)
    result = pretrain(tuned, folder_library, out=tmp_path / "tuned.pt", progress=False, on_epoch=lambda *_: None)
    about = result.metadata["initialised_from"]
    assert about["path"] == str(trained.checkpoint) and about["command"] == "test" and len(about["sha256"]) == 16
    # After one epoch it is still about where the checkpoint was, far from fresh weights' first epoch.
    first = result.metadata["history"]["stage1"][0]["val_monaural_l1"]
    assert first < trained.metadata["history"]["stage1"][0]["val_monaural_l1"]
    with pytest.raises(CheckpointError):
        pretrain(dataclasses.replace(tuned, init_from=str(tmp_path / "missing.pt")), folder_library,
                 out=tmp_path / "other.pt", progress=False)


def test_refiner_memory_resets_per_sequence(trained):
    separator = trained.separator.eval()
    torch.manual_seed(0)
    estimates = torch.rand(4, 5, 16, 32, 32) * 10
    with torch.no_grad():
        together = _refine_sequences(separator, estimates)
        alone = _refine_sequences(separator, estimates[2:3])
        # Step 0 of a sequence starts from fresh memory: the current estimate only.
        first = separator.refine(estimates[:, 0], None)
        changed = estimates.clone()
        changed[:, 0] *= 2.0
        carried = _refine_sequences(separator, changed)
    torch.testing.assert_close(together[2:3], alone)
    torch.testing.assert_close(together[:, 0], first)
    assert not torch.allclose(carried[:, 1], together[:, 1])  # step 1 remembers step 0


def test_passive_eval_scores_floor_separator_and_oracle(trained, small_val_stream, folder_library):
    loaded = load_separator(trained.checkpoint)
    episode_config = dataclasses.replace(small_val_stream.episodes[0], count=6)
    assert isinstance(episode_config, EpisodeConfig)
    episodes = episodes_for(episode_config, folder_library)
    scores = evaluate_passive(loaded, episodes, folder_library, env_config=small_val_stream.env, n_envs=4,
                              progress=False)
    for estimate in ESTIMATES:
        for metric in METRICS:
            assert scores[estimate][metric].shape == (6,) and np.isfinite(scores[estimate][metric]).all()
    env = BatchEnv(episodes, folder_library, n_envs=6, config=small_val_stream.env, autoreset=False)
    obs, info = env.reset(episodes=episodes)
    # The floor of the deployable variant: the ear-mean mixture against the target as heard.
    floor = si_sdr(obs["audio"].mean(axis=1), info["target_binaural"].mean(axis=1))
    np.testing.assert_allclose(scores["mixture"]["si_sdr_mixture_phase"], floor, atol=1e-3)
    summary = summarize(scores)
    assert summary["oracle"]["si_sdr"] > summary["mixture"]["si_sdr"] + 1.0
    assert summary["oracle"]["stft_distance"] < summary["mixture"]["stft_distance"]
    gap = gap_closed(summary, "si_sdr")
    expected = (summary["separator"]["si_sdr"] - summary["mixture"]["si_sdr"]) / (
        summary["oracle"]["si_sdr"] - summary["mixture"]["si_sdr"])
    assert gap == pytest.approx(expected) and summary["mixture"]["episodes"] == 6


def test_config_validation(small_stream):
    with pytest.raises(ConfigError, match="lr"):
        PretrainConfig(lr=0.0)
    with pytest.raises(ConfigError, match="model"):
        PretrainConfig(model="compact")
    with pytest.raises(ConfigError, match="batches_per_epoch"):
        PretrainConfig(batches_per_epoch=0)
    with pytest.raises(ConfigError, match="single observations"):
        PretrainConfig(train_data=dataclasses.replace(small_stream, steps=2))
    assert isinstance(Separator(PretrainConfig().model), Separator)
    with pytest.raises(ConfigError, match="device"):
        PretrainConfig(device="gpu")
    assert PretrainConfig(device="cpu").torch_device() == torch.device("cpu")
    assert "device" not in PretrainConfig().result_fields()  # a run may resume on another device
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no CUDA device"):
            PretrainConfig(device="cuda").torch_device()


def test_the_command_line_selects_the_backbone():
    parser = build_parser()
    assert config_from_args(parser.parse_args([])).model == SeparatorConfig.preset("compact")
    dense = config_from_args(parser.parse_args(["--backbone", "mmdensenet", "--epochs", "3"]))
    assert dense.model == SeparatorConfig(backbone="mmdensenet") and dense.epochs == 3
    with pytest.raises(SystemExit):
        parser.parse_args(["--backbone", "transformer"])


def test_the_command_line_augments_the_training_streams_only():
    augmented = config_from_args(build_parser().parse_args(["--eq-db", "6", "--speed-min", "0.85"]))
    assert augmented.train_data.eq_db == augmented.refiner_data.eq_db == 6.0 and augmented.val_data.eq_db == 0.0
    assert augmented.train_data.speed_min == augmented.refiner_data.speed_min == 0.85
    assert augmented.val_data.speed_min == 1.0
    plain = config_from_args(build_parser().parse_args([]))
    assert plain.train_data.eq_db == 0.0 and plain.train_data.speed_min == 1.0
