"""Evaluation jobs on Ray: the same table from 1 and 2 workers, and the same as in-process."""

import dataclasses

import pytest

from m2h_ros.errors import ConfigError
from m2h_ros.experiments.jobs import EvalJob, run_eval_job, run_jobs
from m2h_ros.experiments.sweep import Condition, Sweep, run_sweep, with_estimates, write_sweep


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
    paths = write_sweep(results, rows, tmp_path, title="t", xlabel="m", command="python x.py", meta={}, started=0.0)
    table = paths["markdown"].read_text()
    assert "| random | sources >= 2.0 m, no f^R | near_target | unheard | 2 |" in table
    assert paths["plot"].stat().st_size > 0
    with pytest.raises(ConfigError, match="unknown controller 'teleport'"):
        Sweep(controllers=["teleport"], tasks=["near_target"], sound_splits=["unheard"], conditions=conditions)
