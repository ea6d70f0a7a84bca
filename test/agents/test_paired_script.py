"""scripts/paired.py: paired differences from results files already written, across runs."""

import pytest

from m2h_ros.core.results import EpisodeResult, write_results


@pytest.fixture(scope="module")
def paired(script):
    return script("paired")


def run(controller: str, finals: dict[str, float]) -> list[EpisodeResult]:
    return [EpisodeResult(episode_id=episode, controller=controller, task="near_target", sound_split="heard",
                          scene_id="s", target_class="speech", actions=[0], si_sdr=[0.0, final],
                          si_sdr_mixture_phase=[0.0, -final], stft_distance=[1.0, 2.0])
            for episode, final in finals.items()]


def test_runs_written_apart_compare_episode_by_episode(paired, tmp_path, capsys):
    first = write_results(run("doa", {"a": 1.0, "b": 3.0}) + run("stand_in_place", {"a": 0.0, "b": 0.0}),
                          tmp_path / "one", plot=False)["json"]
    # Another run over the same episodes plus one the reference never played (left out of the pairs).
    second = write_results(run("move2hear", {"b": 4.0, "a": 3.0, "c": 9.0}), tmp_path / "two", plot=False)["json"]
    out = tmp_path / "paired.md"
    assert paired.main([str(first), str(second), "--reference", "doa,stand_in_place", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith(f"Command: `python scripts/paired.py {first} {second} --reference doa,stand_in_place")
    assert "| move2hear | near_target | heard | 2 | +1.50 ± 6.35 |" in text  # (2, 1): mean 1.5, t(1) CI
    assert "| stand_in_place | near_target | heard | 2 | -2.00 ± 12.71 |" in text
    assert "minus stand_in_place's" in text and "| doa | near_target | heard | 2 | +2.00 ± 12.71 |" in text
    assert paired.main([str(first), str(second), "--reference", "doa", "--metric", "si_sdr_mixture_phase"]) == 0
    assert "| move2hear | near_target | heard | 2 | -1.50 ± 6.35 |" in capsys.readouterr().out
    # The reference evaluated again, identically, beside the second run counts once.
    again = write_results(run("doa", {"a": 1.0, "b": 3.0}) + run("move2hear", {"b": 4.0, "a": 3.0}),
                          tmp_path / "again", plot=False)["json"]
    assert paired.main([str(first), str(again), "--reference", "doa"]) == 0
    assert "| move2hear | near_target | heard | 2 | +1.50 ± 6.35 |" in capsys.readouterr().out


def test_unknown_reference_and_a_run_read_twice_are_clear_errors(paired, tmp_path, capsys):
    path = write_results(run("doa", {"a": 1.0}), tmp_path, plot=False)["json"]
    assert paired.main([str(path), "--reference", "oracle"]) == 2
    assert "reference 'oracle' is not in the results; they hold doa" in capsys.readouterr().err
    other = write_results(run("doa", {"a": 2.0}), tmp_path / "other", plot=False)["json"]
    assert paired.main([str(path), str(other), "--reference", "doa"]) == 2
    assert f"doa played episode a differently in {path} and {other} (two runs of it: name them with --tags)" \
        in capsys.readouterr().err
    assert paired.main([str(path), str(path), "--tags", "one", "--reference", "doa:one"]) == 2
    assert "--tags names 1 runs for 2 results files" in capsys.readouterr().err
    assert paired.main([str(tmp_path / "missing.json"), "--reference", "doa"]) == 2
    assert "cannot read results file" in capsys.readouterr().err


def test_tags_tell_two_runs_of_one_controller_apart(paired, tmp_path, capsys):
    shipped = write_results(run("move2hear", {"a": 1.0, "b": 2.0}), tmp_path / "shipped", plot=False)["json"]
    candidate = write_results(run("move2hear", {"a": 2.0, "b": 4.0}), tmp_path / "candidate", plot=False)["json"]
    assert paired.main([str(shipped), str(candidate), "--tags", "shipped,candidate",
                        "--reference", "move2hear:shipped"]) == 0
    out = capsys.readouterr().out
    assert "minus move2hear:shipped's" in out and "| move2hear:candidate | near_target | heard | 2 | +1.50 ± 6.35 |" in out
    # A controller evaluated identically beside each run keeps its name: one row, not one per tag; asked for
    # by a tagged name, it is found all the same.
    base = run("stand_in_place", {"a": 0.0, "b": 0.0})
    shipped = write_results(run("move2hear", {"a": 1.0, "b": 2.0}) + base, tmp_path / "shipped2", plot=False)["json"]
    candidate = write_results(run("move2hear", {"a": 2.0, "b": 4.0}) + base, tmp_path / "candidate2",
                              plot=False)["json"]
    rows = paired.differences(paired.load([shipped, candidate], ["shipped", "candidate"]),
                              ["stand_in_place:shipped"], "si_sdr")["stand_in_place"]
    assert sorted(r["controller"] for r in rows) == ["move2hear:candidate", "move2hear:shipped"]


def test_forest_plot_orders_controllers_by_their_difference(paired, tmp_path, capsys):
    from m2h_ros.core.results import forest_order

    path = write_results(run("stand_in_place", {"a": 0.0, "b": 0.0}) + run("doa", {"a": 1.0, "b": 1.0})
                         + run("random", {"a": -1.0, "b": -3.0}) + run("move2hear", {"a": 2.0, "b": 4.0}),
                         tmp_path, plot=False)["json"]
    png = tmp_path / "forest.png"
    assert paired.main([str(path), "--reference", "stand_in_place", "--png", str(png)]) == 0
    assert f"plot: {png}" in capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = paired.differences(paired.load([path], []), ["stand_in_place"], "si_sdr")["stand_in_place"]
    assert forest_order(rows) == ["random", "doa", "move2hear"]  # drawn bottom to top: the best on top
    # A reference that shares no episode with anything leaves nothing to draw: said, not an empty figure.
    alone = write_results(run("doa", {"z": 1.0}) + run("random", {"y": 0.0}), tmp_path / "alone", plot=False)["json"]
    assert paired.main([str(alone), "--reference", "doa", "--png", str(tmp_path / "none.png")]) == 2
    assert "no paired differences to plot" in capsys.readouterr().err


def test_a_committed_csv_pairs_as_its_json_does(paired, tmp_path, capsys):
    """docs/results keeps results.csv in git, not results.json: a CSV's final scores pair the same, and the
    same run read once from each counts once."""
    written = write_results(run("doa", {"a": 1.25, "b": 3.0}) + run("stand_in_place", {"a": 0.0, "b": 0.5}),
                            tmp_path / "one", plot=False)
    candidate = write_results(run("move2hear", {"a": 3.0, "b": 4.0}) + run("doa", {"a": 1.25, "b": 3.0}),
                              tmp_path / "two", plot=False)["json"]
    tables = []
    for first in (written["json"], written["csv"]):
        assert paired.main([str(first), str(candidate), "--reference", "doa,stand_in_place"]) == 0
        tables.append(capsys.readouterr().out)
    assert tables[0] == tables[1] and "| move2hear | near_target | heard | 2 | +1.38 ± 4.76 |" in tables[0]
    other = write_results(run("doa", {"a": 1.0, "b": 3.0}), tmp_path / "other", plot=False)["json"]
    assert paired.main([str(written["csv"]), str(other), "--reference", "doa"]) == 2  # another run of doa
    assert f"doa played episode a differently in {written['csv']} and {other}" in capsys.readouterr().err


def test_a_sweeps_conditions_pair_as_controllers_of_their_own(paired, tmp_path, capsys):
    sweep = run("move2hear", {"a": 1.0, "b": 2.0}) + run("move2hear", {"a": 3.0, "b": 5.0})
    for result, condition in zip(sweep, ("T = 0", "T = 0", "T = 20", "T = 20"), strict=True):
        result.condition = condition
    swept = write_results(sweep, tmp_path / "sweep", plot=False)["csv"]
    plain = write_results(run("move2hear", {"a": 2.0, "b": 2.0}), tmp_path / "plain", plot=False)["json"]
    assert paired.main([str(swept), str(plain), "--tags", "sweep,plain", "--reference", "move2hear[T = 20]"]) == 0
    out = capsys.readouterr().out
    assert "minus move2hear[T = 20]'s" in out
    assert "| move2hear[T = 0] | near_target | heard | 2 | -2.50 ± 6.35 |" in out
    assert "| move2hear | near_target | heard | 2 | -2.00 ± 12.71 |" in out  # the plain run: (-1, -3)


def test_success_and_spl_pair_as_episode_figures(paired, tmp_path, capsys):
    """Far-target navigation: two walkers' success (paired SR) and SPL on the same episodes, from a CSV too."""
    def walks(controller: str, outcomes: dict[str, tuple[bool, float]]) -> list[EpisodeResult]:
        results = run(controller, dict.fromkeys(outcomes, 1.0))
        for result, (success, path_length) in zip(results, outcomes.values(), strict=True):
            result.task, result.success, result.path_length, result.shortest_path = "far_target", success, path_length, 5.0
        return results

    written = write_results(walks("a", {"e1": (True, 5.0), "e2": (False, 9.0), "e3": (True, 10.0)})
                            + walks("b", {"e1": (False, 7.0), "e2": (False, 9.0), "e3": (True, 5.0)}),
                            tmp_path / "walks", plot=False)
    for path in (written["json"], written["csv"]):
        assert paired.main([str(path), "--reference", "b", "--metric", "success"]) == 0
        out = capsys.readouterr().out
        assert "Episode success (SR, 0 or 1) minus b's" in out
        assert "| a | far_target | heard | 3 | +0.33 ± 1.43 |" in out  # (1, 0, 0)
        assert paired.main([str(path), "--reference", "b", "--metric", "spl"]) == 0
        assert "| a | far_target | heard | 3 | +0.17 ± 1.90 |" in capsys.readouterr().out  # (1, 0, -0.5)


def test_a_larger_run_pairs_on_a_smaller_runs_episodes(paired, tmp_path, capsys):
    path = write_results(run("stand_in_place", {"e0": 0.0, "e1": 0.0, "e2": 0.0})
                         + run("move2hear", {"e0": 1.0, "e1": 3.0, "e2": 100.0})
                         + run("doa", {"e0": 5.0, "e1": 5.0, "e2": 5.0}), tmp_path, plot=False)["json"]
    assert paired.main([str(path), "--reference", "stand_in_place", "--controllers", "stand_in_place,move2hear",
                        "--count", "2"]) == 0
    out = capsys.readouterr().out
    assert "| move2hear | near_target | heard | 2 | +2.00 ± 12.71 |" in out  # e2 left out
    assert "doa" not in out
    assert paired.main([str(path), "--reference", "stand_in_place", "--controllers", "oracle"]) == 2
    assert "--controllers names oracle, not in the results; they hold doa, move2hear, stand_in_place" \
        in capsys.readouterr().err
    assert paired.main([str(path), "--reference", "stand_in_place", "--count", "0"]) == 2
    assert "--count 0 must be at least 1" in capsys.readouterr().err
