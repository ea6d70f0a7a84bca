"""The command line every sweep script shares: which controllers, tasks, splits and episodes, where
the jobs run (local Ray CPUs or a cluster), where the report goes."""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from m2h_ros.errors import M2HError
from m2h_ros.experiments.sweep import Condition, Sweep, estimate_pairs, run_sweep, write_sweep
from m2h_ros.paths import RUNS_DIR, file_sha256, repo_relative


def _separators(conditions: Sequence[Condition]) -> dict:
    """The separator checkpoints the conditions name (repo-relative path, sha256 prefix), for the meta."""
    named = {c.label: Path(c.separator) for c in conditions if c.separator}
    return {"separators": {label: {"path": repo_relative(path),
                                   "sha256": file_sha256(path)}
                           for label, path in named.items()}} if named else {}


def sweep_main(argv: Sequence[str] | None, *, script: str, doc: str, title: str, xlabel: str,
               conditions: Callable[[argparse.Namespace], list[Condition]],
               add_arguments: Callable[[argparse.ArgumentParser], None] = lambda parser: None,
               controllers: str = "stand_in_place,move2hear_quality", task: str = "near_target",
               sound_split: str = "heard,unheard", reference: str | None = "stand_in_place",
               condition_reference: str | None = None) -> int:
    """Parse, run the sweep, write ``runs/experiments/<script stem>/`` (or --out); 2 on a clear error.
    ``script``: the script's ``__file__`` (in ``scripts/experiments/`` of the repository);
    ``reference`` / ``condition_reference``: the paired comparisons of :func:`write_sweep` (the reference
    controller only where the sweep plays it)."""
    script = repo_relative(script)
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--task", default=task, help="near_target, far_target or both comma-separated")
    parser.add_argument("--sound-split", default=sound_split)
    parser.add_argument("--controllers", default=controllers, help="comma-separated registry names")
    parser.add_argument("--count", type=int, default=200, help="test episodes per task x split x condition")
    parser.add_argument("--chunk", type=int, default=50, help="episodes per Ray job")
    parser.add_argument("--workers", type=int, default=2, help="local Ray CPUs (ignored with --address)")
    parser.add_argument("--address", help="an existing Ray cluster ('auto': the one this machine is in)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the stochastic controllers")
    parser.add_argument("--out", type=Path, default=RUNS_DIR / "experiments" / Path(script).stem,
                        help="output folder (default: %(default)s; the committed tables are under "
                             "docs/results/experiments/, written only when --out names them)")
    parser.add_argument("--separator", type=Path,
                        help="separator checkpoint of the conditions that name none (default: the shipped one; "
                             "m2h_ros/models/default/separator_compact_pretrained.pt re-runs a table made with the "
                             "passively pretrained f^R)")
    parser.add_argument("--policy-checkpoint", type=Path,
                        help="the learned controllers' policy file (move2hear: a folder of them); default: the shipped ones")
    parser.add_argument("--no-progress", action="store_true")
    add_arguments(parser)
    args = parser.parse_args(argv)
    command = shlex.join(["python", script, *(sys.argv[1:] if argv is None else argv)])
    started = time.perf_counter()
    try:
        swept = conditions(args)
        if args.separator:  # absolute: Ray workers run elsewhere
            swept = [c if c.separator else dataclasses.replace(c, separator=str(args.separator.resolve()))
                     for c in swept]
        sweep = Sweep(controllers=args.controllers.split(","), tasks=args.task.split(","),
                      sound_splits=args.sound_split.split(","), conditions=swept, count=args.count,
                      chunk=args.chunk, seed=args.seed,
                      controller_checkpoint=str(args.policy_checkpoint.resolve()) if args.policy_checkpoint else "")
        results, rows = run_sweep(sweep, workers=args.workers, address=args.address,
                                  progress=not args.no_progress, desc=Path(script).stem)
    except (M2HError, ValueError) as exc:
        print(f"{Path(script).name}: error: {exc}", file=sys.stderr)
        return 2
    meta = {"count": args.count, "controller_seed": args.seed, "workers": args.address or args.workers,
            "conditions": [c.label for c in sweep.conditions],
            **_separators(sweep.conditions),
            **({"policy_checkpoint": repo_relative(args.policy_checkpoint)} if args.policy_checkpoint else {})}
    paths = write_sweep(results, rows, args.out, title=title, xlabel=xlabel, command=command, meta=meta,
                        started=started, reference=reference if reference in sweep.controllers else None,
                        condition_reference=condition_reference or estimate_pairs(sweep.conditions) or None)
    print(paths["markdown"].read_text())
    print(", ".join(f"{kind}: {path}" for kind, path in paths.items()))
    return 0


def switch_step_main(argv: Sequence[str] | None = None, *, script: str, doc: str, option: str, symbol: str, task: str,
                     steps: str, reference_step: int, scene_split: str, title: str, xlabel: str) -> int:
    """A sweep of one of ``move2hear``'s switch steps (``option``: far-target ``switch_step``, near-target
    ``near_switch_step``) over ``--switch-steps``; conditions are labelled "``symbol`` = step" and compared with
    ``reference_step``'s on the same episodes; ``--scene-split val`` to choose the step, test to report it."""

    def label(step: int) -> str:
        return f"{symbol} = {step}"

    def conditions(args: argparse.Namespace) -> list[Condition]:
        return [Condition(label=label(step), x=step, controller={option: step},
                          episodes={"scene_split": args.scene_split})
                for step in (int(v) for v in args.switch_steps.split(","))]

    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--switch-steps", default=steps)
        parser.add_argument("--scene-split", default=scene_split, choices=("val", "test"),
                            help=f"val to choose {symbol}, test to report it")

    return sweep_main(argv, script=script, doc=doc, conditions=conditions, controllers="move2hear", task=task,
                      title=title, xlabel=xlabel, add_arguments=arguments, condition_reference=label(reference_step))
