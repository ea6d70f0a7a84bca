"""Evaluation jobs on Ray: the same table from 1 and 2 workers, and the same as in-process."""

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from m2h_ros.core.results import EpisodeResult, paired_differences
from m2h_ros.errors import ConfigError
from m2h_ros.experiments.jobs import EvalJob, run_eval_job, run_jobs
from m2h_ros.paths import REPO_DIR
from m2h_ros.experiments.sweep import (SWEEP_KEYS, Condition, Sweep, estimate_pairs, run_sweep, sweep_jobs, with_estimates,
                                       write_sweep)


@pytest.mark.timeout(300)
def test_one_and_two_workers_give_the_same_results(small_episodes, folder_library, env_config):
    episodes = tuple(small_episodes(count=4, max_steps=3, seed=11))
    jobs = [EvalJob(controller=name, episodes=episodes[half::2], env=env_config, library=folder_library,
                    estimate=estimate, condition=f"{estimate}", slots=2, seed=3)
            for name in ("random", "doa") for half in (0, 1) for estimate in ("refined", "monaural")]
    one = run_jobs(run_eval_job, jobs, workers=1, progress=False)
    two = run_jobs(run_eval_job, jobs, workers=2, progress=False)
    assert [[r.to_dict() for r in job] for job in one] == [[r.to_dict() for r in job] for job in two]
    assert [r.to_dict() for r in one[0]] == [r.to_dict() for r in run_eval_job(jobs[0])]  # Ray changes nothing
    refined, monaural = one[0], one[1]
    assert [r.condition for r in refined + monaural] == ["refined"] * 2 + ["monaural"] * 2
    assert [r.actions for r in refined] == [r.actions for r in monaural]  # same play, other estimate scored
    assert [r.si_sdr for r in refined] != [r.si_sdr for r in monaural]


def test_bad_jobs_are_refused(small_episodes, env_config):
    with pytest.raises(ConfigError, match="at least one episode"):
        EvalJob(controller="doa", episodes=(), env=env_config)
    job = EvalJob(controller="doa", episodes=tuple(small_episodes(count=1, max_steps=1)), env=env_config)
    with pytest.raises(ConfigError, match="slots"):
        dataclasses.replace(job, slots=0)
    with pytest.raises(ConfigError, match="workers"):
        run_jobs(run_eval_job, [job], workers=0)


def test_a_sweep_writes_its_table_and_curve(folder_library, fast_acoustics, tmp_path):
    small = {"scene_preset": "small", "near_radius": 2.0, "max_steps": 2, "count": 4}
    conditions = with_estimates([Condition(label=f"sources >= {d} m", x=d, env={"acoustics": fast_acoustics},
                                           episodes={**small, "min_source_distance": d}) for d in (1.0, 2.0)])
    sweep = Sweep(controllers=["stand_in_place", "random"], tasks=["near_target"], sound_splits=["unheard"],
                  conditions=conditions, count=2, chunk=1, library=folder_library)
    results, rows = run_sweep(sweep, workers=2, progress=False)
    assert len(results) == 2 * 4 * 2 and len(rows) == 2 * 4
    assert {r["condition"] for r in rows} == {"sources >= 1.0 m, f^R", "sources >= 1.0 m, no f^R",
                                              "sources >= 2.0 m, f^R", "sources >= 2.0 m, no f^R"}
    assert all(r["episodes"] == 2 and r["series"] in ("", "no f^R") for r in rows)
    pairs = estimate_pairs(conditions)
    assert pairs == {"sources >= 1.0 m, f^R": "sources >= 1.0 m, no f^R", "sources >= 2.0 m, f^R": "sources >= 2.0 m, no f^R"}
    paths = write_sweep(results, rows, tmp_path, title="t", xlabel="m", command="python x.py", meta={}, started=0.0,
                        condition_reference=pairs)
    table = paths["markdown"].read_text()
    assert "| random | sources >= 2.0 m, no f^R | near_target | unheard | 2 |" in table
    # f^R's gain: each f^R condition against its own "no f^R" twin, per controller, on the same episodes.
    versus = json.loads(paths["json"].read_text())["meta"]["paired_conditions"]
    assert sorted((r["controller"], r["condition"], r["reference"]) for r in versus) == [
        (c, f"sources >= {d} m, f^R", f"sources >= {d} m, no f^R") for c in ("random", "stand_in_place")
        for d in ("1.0", "2.0")]
    assert "minus the same condition's no f^R (f^M's estimate)" in table
    assert paths["plot"].stat().st_size > 0
    with pytest.raises(ConfigError, match="unknown controller 'teleport'"):
        Sweep(controllers=["teleport"], tasks=["near_target"], sound_splits=["unheard"], conditions=conditions)


def _result(controller: str, condition: str, episode: str, final: float) -> EpisodeResult:
    return EpisodeResult(episode_id=episode, controller=controller, task="near_target", sound_split="heard",
                         scene_id="s", target_class="speech", si_sdr=[0.0, final], si_sdr_mixture_phase=[0.0, 0.0],
                         stft_distance=[1.0, 1.0], condition=condition)


def test_paired_differences_per_condition_and_between_conditions(tmp_path):
    finals = {("stand", "a"): (1.0, 2.0), ("move", "a"): (2.0, 4.0), ("stand", "b"): (3.0, 3.0),
              ("move", "b"): (5.0, 4.0)}
    results = [_result(c, cond, f"e{i}", v) for (c, cond), values in finals.items() for i, v in enumerate(values)]
    by_controller = paired_differences(results, reference="stand", by=SWEEP_KEYS)
    assert [(r["controller"], r["condition"], r["difference"]) for r in by_controller] == [
        ("move", "a", pytest.approx(1.5)), ("move", "b", pytest.approx(1.5))]
    by_condition = paired_differences(results, reference="a", by=SWEEP_KEYS, vary="condition")
    assert [(r["controller"], r["condition"], r["difference"], r["episodes"]) for r in by_condition] == [
        ("stand", "b", pytest.approx(1.5), 2), ("move", "b", pytest.approx(1.5), 2)]
    assert by_condition[1]["ci95"] == pytest.approx(stats.t.ppf(0.975, 1) * np.std([3.0, 0.0], ddof=1) / np.sqrt(2))
    with pytest.raises(ConfigError, match="grouping fields"):
        paired_differences(results, reference="a", vary="condition")
    own = paired_differences(results, reference={"a": "b"}, by=SWEEP_KEYS, vary="condition")  # a against b only
    assert [(r["controller"], r["condition"], r["reference"], r["difference"]) for r in own] == [
        ("stand", "a", "b", pytest.approx(-1.5)), ("move", "a", "b", pytest.approx(-1.5))]
    rows = [{"controller": "move", "task": "near_target", "sound_split": "heard", "condition": "a", "x": "a",
             "series": "", "episodes": 2, "si_sdr": 3.0, "ci95": 1.0}]
    paths = write_sweep(results, rows, tmp_path, title="t", xlabel="x", command="c", meta={}, started=0.0,
                        reference="stand", condition_reference="a")
    table = paths["markdown"].read_text()
    assert "| move | b | near_target | heard | 2 | +1.50 ±" in table  # vs stand, in condition b
    assert "minus the 'a' condition's" in table and "| stand | b | near_target | heard | 2 | +1.50 ±" in table
    assert json.loads(paths["json"].read_text())["meta"]["paired_conditions"][0]["reference"] == "a"


def test_a_condition_passes_its_separator_to_the_jobs(folder_library, fast_acoustics):
    small = {"scene_preset": "small", "near_radius": 2.0, "max_steps": 2, "count": 2, "min_source_distance": 1.0}
    conditions = [Condition(label=label, x=label, separator=path, episodes=small, env={"acoustics": fast_acoustics})
                  for label, path in (("shipped", ""), ("other", "/tmp/other.pt"))]
    sweep = Sweep(controllers=["stand_in_place"], tasks=["near_target"], sound_splits=["unheard"],
                  conditions=conditions, count=2, chunk=2, library=folder_library)
    jobs, keys = sweep_jobs(sweep, folder_library)
    assert [(job.condition, job.separator) for job in jobs] == [("shipped", ""), ("other", "/tmp/other.pt")]
    assert [key[3] for key in keys] == [0, 1]


@pytest.fixture
def sweeps_asked(monkeypatch):
    """The Sweeps the command line built, each stopped before it runs (sweep_main then returns 2)."""
    from m2h_ros.experiments import cli  # noqa: PLC0415

    seen = []

    def stop_at_the_sweep(sweep, **_):
        seen.append(sweep)
        raise ConfigError("stopped before running")

    monkeypatch.setattr(cli, "run_sweep", stop_at_the_sweep)
    return seen


def test_the_separator_flag_sets_the_conditions_that_name_none(sweeps_asked, tmp_path):
    from m2h_ros.experiments import cli  # noqa: PLC0415

    def conditions(args):
        return [Condition(label="own", x=0, separator="/elsewhere/own.pt"), Condition(label="any", x=1)]

    argv = ["--separator", str(tmp_path / "pretrained.pt"), "--out", str(tmp_path)]
    assert cli.sweep_main(argv, script="scripts/experiments/x.py", doc="x", title="x", xlabel="x",
                          conditions=conditions) == 2
    assert [c.separator for c in sweeps_asked[0].conditions] == ["/elsewhere/own.pt", str(tmp_path / "pretrained.pt")]
    cli.sweep_main(["--out", str(tmp_path)], script="scripts/experiments/x.py", doc="x", title="x", xlabel="x",
                   conditions=conditions)
    assert [c.separator for c in sweeps_asked[1].conditions] == ["/elsewhere/own.pt", ""]  # the shipped one


def test_the_policy_checkpoint_flag_reaches_every_job(sweeps_asked, tmp_path, folder_library):
    from m2h_ros.experiments import cli  # noqa: PLC0415

    small = {"scene_preset": "small", "near_radius": 2.0, "max_steps": 2, "count": 2, "min_source_distance": 1.0}
    argv = ["--policy-checkpoint", str(tmp_path / "folder"), "--count", "2", "--controllers", "stand_in_place,move2hear",
            "--sound-split", "unheard", "--out", str(tmp_path)]
    assert cli.sweep_main(argv, script="scripts/experiments/x.py", doc="x", title="x", xlabel="x",
                          conditions=lambda args: [Condition(label="a", x=0, episodes=small)]) == 2
    assert [job.controller_checkpoint for job in sweep_jobs(sweeps_asked[0], folder_library)[0]] == ["", str(tmp_path / "folder")]  # learned ones only
    cli.sweep_main(["--count", "2", "--controllers", "stand_in_place", "--sound-split", "unheard", "--out",
                    str(tmp_path)], script="scripts/experiments/x.py", doc="x", title="x", xlabel="x",
                   conditions=lambda args: [Condition(label="a", x=0, episodes=small)])
    assert [job.controller_checkpoint for job in sweep_jobs(sweeps_asked[1], folder_library)[0]] == [""]  # the shipped ones


def test_a_switch_step_sweep_sets_its_option_per_condition(sweeps_asked, tmp_path):
    from m2h_ros.experiments import cli  # noqa: PLC0415

    assert cli.switch_step_main(["--switch-steps", "0,7", "--out", str(tmp_path)], script="scripts/experiments/x.py",
                                doc="x", option="near_switch_step", symbol="T", task="near_target", steps="0,5",
                                reference_step=0, scene_split="val", title="x", xlabel="x") == 2
    (sweep,) = sweeps_asked
    assert list(sweep.controllers) == ["move2hear"] and list(sweep.tasks) == ["near_target"]
    assert [(c.label, c.controller, c.episodes) for c in sweep.conditions] == [
        ("T = 0", {"near_switch_step": 0}, {"scene_split": "val"}), ("T = 7", {"near_switch_step": 7}, {"scene_split": "val"})]


@pytest.mark.parametrize("script", ["scenarios", "switch_time", "reward", "approach_oracle", "scene_generalisation"])
def test_an_experiment_writes_under_runs_unless_told(script):
    """A plain rerun must not overwrite the committed tables under docs/results/."""
    result = subprocess.run([sys.executable, str(REPO_DIR / "scripts" / "experiments" / f"{script}.py"), "--help"],
                            capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "400"})
    assert result.returncode == 0, result.stderr
    assert f"{REPO_DIR / 'runs'}/" in " ".join(result.stdout.split()), result.stdout
    assert "default: " + str(REPO_DIR / "docs") not in " ".join(result.stdout.split())
