"""Evaluation jobs on Ray: the same table from 1 and 2 workers, and the same as in-process."""

import dataclasses

import pytest

from m2h_ros.errors import ConfigError
from m2h_ros.experiments.jobs import EvalJob, run_eval_job, run_jobs


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
