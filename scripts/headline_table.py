#!/usr/bin/env python3
"""The README's headline table: each result the Move2Hear paper reports beside ours with the shipped
models, computed from the result files committed in docs/results/ (never typed by hand).

    python scripts/headline_table.py                    # print the table
    python scripts/headline_table.py --check README.md  # exit 1 when README's table differs from it
    python scripts/headline_table.py --write README.md  # put it between README's markers
    python scripts/headline_table.py --results DIR ...  # read another copy of docs/results/

Ours: final-step SI-SDR (dB, ground-truth phase, the paper's variant), paired over the same episodes,
mean ± 95% CI, heard / unheard sounds; SR and SPL in percent. Where the paper reports a finding rather
than a number, the paper column says so.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from m2h_ros.core.results import EpisodeResult, mean_ci, read_final_scores
from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.paths import REPO_DIR

START = "<!-- headline-table:start (scripts/headline_table.py --write README.md) -->"
END = "<!-- headline-table:end -->"
SPLITS = ("heard", "unheard")
FAR_BASELINES = ("far_target/stand_in_place_gan_et_al", "far_target/baselines")
BASELINES = ("rotate_in_place", "random", "move_forward", "doa", "proximity_prior", "novelty", "av_navigator",
             "gan_et_al")
NAMES = {"gan_et_al": "Gan et al.", "novelty": "Novelty", "doa": "DoA", "proximity_prior": "Proximity Prior",
         "move_forward": "Move Forward", "av_navigator": "AV Navigator", "random": "Random",
         "rotate_in_place": "Rotate In-Place"}


class Results:
    """The committed results.csv files under one docs/results/ folder, read once each."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._read: dict[str, list[EpisodeResult]] = {}

    def episodes(self, *folders: str) -> list[EpisodeResult]:
        out = []
        for folder in folders:
            if folder not in self._read:
                self._read[folder] = read_final_scores(self.root / folder / "results.csv")
            out += self._read[folder]
        return out

    def gain(self, folders: Sequence[str], controller: str, reference: str, *, condition: str = "",
             reference_condition: str | None = None, metric: str = "si_sdr") -> dict[str, tuple[float, float]]:
        """controller minus reference on the same episodes, per sound split: {split: (mean, ci95)}."""
        reference_condition = condition if reference_condition is None else reference_condition
        ours = {(r.sound_split, r.episode_id): r.final(metric) for r in self.episodes(*folders)
                if r.controller == controller and r.condition == condition}
        theirs = {(r.sound_split, r.episode_id): r.final(metric) for r in self.episodes(*folders)
                  if r.controller == reference and r.condition == reference_condition}
        out = {}
        for split in SPLITS:
            shared = sorted(k for k in ours.keys() & theirs.keys() if k[0] == split)
            if shared:
                out[split] = mean_ci([ours[k] - theirs[k] for k in shared])
        if not out:
            raise ConfigError(f"no shared episodes of {controller!r} ({condition!r}) and {reference!r} in {folders}")
        return out

    def rate(self, folders: Sequence[str], controller: str, metric: str, *, condition: str = "",
             split: str = "heard") -> float:
        values = [r.final(metric) for r in self.episodes(*folders)
                  if r.controller == controller and r.condition == condition and r.sound_split == split]
        if not values:
            raise ConfigError(f"no {split} episodes of {controller!r} ({condition!r}) in {folders}")
        return 100.0 * sum(values) / len(values)

    def count(self, folder: str, controller: str) -> int:
        return sum(1 for r in self.episodes(folder) if r.controller == controller and r.sound_split == "heard")


def _pm(value: tuple[float, float], *, ci: bool = True) -> str:
    mean, half = value
    return f"{mean:+.2f} ± {half:.2f}" if ci else f"{mean:+.2f}"


def _pair(gains: dict[str, tuple[float, float]], *, ci: bool = True) -> str:
    return " / ".join(_pm(gains[s], ci=ci) for s in SPLITS)


def _link(folder: str) -> str:
    return f"[{folder}](docs/results/{folder}/)"


def _against_baselines(res: Results, folders: Sequence[str], controller: str) -> str:
    """How many baselines the controller beats with the paired CI above zero, and the nearest one."""
    gains = {b: res.gain(folders, controller, b) for b in BASELINES}
    above = sum(all(m - h > 0 for m, h in g.values()) for g in gains.values())
    nearest = min(gains, key=lambda b: sum(m for m, _ in gains[b].values()))
    return (f"above {above} of {len(gains)} baselines (paired CI above zero); the nearest, "
            f"{NAMES[nearest]}, by {_pair(gains[nearest])}")


def _above(res: Results, folders: Sequence[str], reference: str, conditions: Sequence[str]) -> str:
    """How many of a sweep's conditions beat the reference condition with the paired CI above zero."""
    n = sum(any(m - h > 0 for m, h in res.gain(folders, "move2hear", "move2hear", condition=c,
                                                  reference_condition=reference).values()) for c in conditions)
    return "none" if n == 0 else f"{n} of {len(conditions)}"


def rows(res: Results) -> list[tuple[str, str, str, str]]:
    """(result, paper, ours, source) per row."""
    near, far = "near_target", "far_target"
    far_all = (far, *FAR_BASELINES)
    n_near, n_far = res.count(near, "move2hear"), res.count(far, "move2hear_navigation")
    out = [
        ("Near-target: Move2Hear's SI-SDR gain over Stand In-Place, dB (heard / unheard)", "+0.88 / +0.95",
         f"**{_pair(res.gain([near], 'move2hear', 'stand_in_place'))}** ({n_near} test episodes per split)",
         _link(near)),
        ("Near-target: Move2Hear against the baselines", "finding: above every baseline",
         _against_baselines(res, [near], "move2hear"), _link(near)),
        ("Far-target: Move2Hear's SI-SDR gain over Stand In-Place, dB", "+3.39 / +2.67",
         f"**{_pair(res.gain(far_all, 'move2hear_navigation', 'stand_in_place'))}** ({n_far} per split)",
         _link(far)),
        ("Far-target: Move2Hear against the baselines", "finding: above every baseline",
         _against_baselines(res, far_all, "move2hear_navigation"), _link(far)),
        ("Navigation (far-target, pi^N + Stop): SR / SPL, %", "70.3 / 54.9",
         "heard {:.1f} / {:.1f}, unheard {:.1f} / {:.1f}; Gan et al. {:.1f} / {:.1f}, {:.1f} / {:.1f}".format(
             *(res.rate(far_all, c, m, split=s) for c in ("move2hear_navigation", "gan_et_al")
               for s in SPLITS for m in ("success", "spl"))),
         _link(far)),
    ]
    noise = {t: f"experiments/noise_robustness/{t}" for t in (near, far)}
    mover = {near: "move2hear_quality", far: "move2hear"}
    out.append((
        "Exp. 1, microphone noise 0 → 0.2 (std / mixture RMS): Move2Hear's gain over Stand In-Place; f^R's part",
        "finding: quality falls with noise; f^R keeps the gain",
        "; ".join(f"{t.split('_')[0]} {_pair(res.gain([noise[t]], mover[t], 'stand_in_place', condition='mic noise 0, f^R'), ci=False)}"
                  f" → {_pair(res.gain([noise[t]], mover[t], 'stand_in_place', condition='mic noise 0.2, f^R'), ci=False)}"
                  for t in (near, far))
        + "; f^R adds " + ", ".join(
            f"{_pair(res.gain([noise[t]], mover[t], mover[t], condition='mic noise 0.2, f^R', reference_condition='mic noise 0.2, no f^R'))} at 0.2 {t.split('_')[0]}"
            for t in (near, far)),
        _link("experiments/noise_robustness")))
    spacing = {t: f"experiments/min_source_distance/{t}" for t in (near, far)}
    out.append((
        "Exp. 2, sources ≥ 2 m → ≥ 8 m apart: Move2Hear's gain over Stand In-Place",
        "finding: closer sources are harder; the gain holds",
        "; ".join(f"{t.split('_')[0]} {_pair(res.gain([spacing[t]], mover[t], 'stand_in_place', condition='sources >= 2 m apart'))}"
                  f" → {_pair(res.gain([spacing[t]], mover[t], 'stand_in_place', condition='sources >= 8 m apart'))}"
                  for t in (near, far)),
        _link("experiments/min_source_distance")))
    switch = "experiments/switch_time"
    out.append((
        "Exp. 3, switch step T^N (far-target, validation, `move2hear:approach`): T^N 60 and 100 minus 80",
        "finding: a switch between the extremes beats both",
        "; ".join(f"{n}: {_pair(res.gain([switch], 'move2hear', 'move2hear', condition=f'T^N = {n}', reference_condition='T^N = 80'))}"
                  for n in (60, 100)) + f"; {_above(res, [switch], 'T^N = 80', ('T^N = 60', 'T^N = 100'))} above 80",
        _link(switch)))
    scenes = "experiments/scenarios"
    out.append((
        "Exp. 4, scenarios (target vs distractor): pi^Q's gain over Stand In-Place, near-target",
        "finding: the gain holds in every scenario",
        ", ".join(f"{s} {_pair(res.gain([scenes], 'move2hear_quality', 'stand_in_place', condition=s), ci=False)}"
                  for s in ("S-vs-S", "S-vs-M", "S-vs-B", "M-vs-B")),
        _link(scenes)))
    backbone, mmd, unet = "experiments/backbone", "MMDenseNet, equal budget", "U-Net, equal budget"
    out.append((
        "Exp. 5, separator backbone at an equal training budget: MMDenseNet-style minus U-Net; pi^Q's gain with it",
        "finding: a stronger backbone helps; motion adds on top",
        f"Stand In-Place {_pair(res.gain([backbone], 'stand_in_place', 'stand_in_place', condition=mmd, reference_condition=unet))}, "
        f"pi^Q {_pair(res.gain([backbone], 'move2hear_quality', 'move2hear_quality', condition=mmd, reference_condition=unet))}; "
        f"pi^Q over Stand In-Place with MMDenseNet {_pair(res.gain([backbone], 'move2hear_quality', 'stand_in_place', condition=mmd))}",
        _link(backbone)))
    reward = "experiments/reward/stage2"
    out.append((
        "Exp. 6, pi^Q's reward (960,000 env steps each): gain over Stand In-Place",
        "finding: compares quality rewards (no number quoted here)",
        ", ".join(f"{name} {_pair(res.gain([reward], f'pi^Q ({key})', 'stand_in_place', condition=f'pi^Q ({key})', reference_condition='stand_in_place'), ci=False)}"
                  for key, name in (("nmse", "NMSE"), ("snr", "SNR"), ("si_sdr", "SI-SDR")))
        + f"; SNR and SI-SDR minus NMSE: {_pair(res.gain([reward], 'pi^Q (snr)', 'pi^Q (nmse)', condition='pi^Q (snr)', reference_condition='pi^Q (nmse)'))}, "
          f"{_pair(res.gain([reward], 'pi^Q (si_sdr)', 'pi^Q (nmse)', condition='pi^Q (si_sdr)', reference_condition='pi^Q (nmse)'))}",
        _link("experiments/reward")))
    nav = "experiments/navigation"
    out.append((
        "Exp. 7, navigation, standard / speaker-target split (heard): SR / SPL, %",
        "finding: pi^N + Stop navigates best in both",
        "; ".join(f"{label} " + ", ".join(
            f"{res.rate([nav], c, 'success', condition=s):.1f} / {res.rate([nav], c, 'spl', condition=s):.1f}"
            for s in ("standard", "speaker-target"))
            for c, label in (("move2hear_navigation", "pi^N + Stop"), ("gan_et_al", "Gan et al."),
                             ("av_navigator", "AV Navigator"))),
        _link(nav)))
    return out


def build_table(results_dir: Path) -> str:
    res = Results(results_dir)
    lines = ["| result | paper | ours, shipped models | source |", "| --- | --- | --- | --- |"]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows(res)]
    return "\n".join(lines)


def _block(table: str) -> str:
    return f"{START}\n{table}\n{END}"


def _current(readme: Path) -> str:
    text = readme.read_text()
    if START not in text or END not in text:
        raise ConfigError(f"{readme} has no headline-table markers ({START!r} ... {END!r})")
    return text[text.index(START):text.index(END) + len(END)]


@reports_errors("headline_table.py")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=REPO_DIR / "docs" / "results",
                        help="the docs/results/ folder to read (default: this checkout's)")
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--check", type=Path, metavar="README", help="exit 1 when its table differs")
    action.add_argument("--write", type=Path, metavar="README", help="replace its table")
    args = parser.parse_args(argv)
    block = _block(build_table(args.results))
    if args.check:
        if _current(args.check) != block:
            print(f"{args.check}: the headline table differs from what docs/results/ gives; run "
                  f"python scripts/headline_table.py --write {args.check}", file=sys.stderr)
            return 1
        return 0
    if args.write:
        text = args.write.read_text()
        args.write.write_text(text.replace(_current(args.write), block))
        return 0
    print(block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
