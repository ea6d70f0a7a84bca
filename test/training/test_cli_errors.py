"""The trainers' commands end a bad value as argparse ends a bad option: one named line, exit code 2."""

from pathlib import Path

import pytest

from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.training import ppo_cli, pretrain_separator, train_locator


@pytest.mark.parametrize(("main", "argv", "line"), [
    (ppo_cli.main, ["--kind", "quality", "--lr", "-1"], "train_policy: error: PPOConfig.lr=-1.0 must be a float in (0, 1]"),
    (train_locator.main, ["--epochs", "0"], "train_locator: error: LocatorTrainConfig.epochs must be an int >= 1, got 0"),
    (pretrain_separator.main, ["--epochs", "0"], "train_separator: error: PretrainConfig.epochs must be an int >= 1, got 0"),
], ids=["train_policy", "train_locator", "train_separator"])
def test_a_bad_value_is_one_line_naming_it(main, argv, line, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == line + "\n"
    assert not (tmp_path / "out").exists()


def test_only_the_projects_errors_are_reported() -> None:
    @reports_errors("tool")
    def fails(error: Exception) -> int:
        raise error

    assert fails(ConfigError("bad")) == 2
    with pytest.raises(KeyError):  # a bug keeps its traceback
        fails(KeyError("bug"))
