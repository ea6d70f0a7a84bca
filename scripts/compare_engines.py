#!/usr/bin/env python3
"""The two RIR engines side by side on one world: the project's and RLRAudioPropagation.

RLRAudioPropagation is opt-in (CC-BY-NC 4.0: scripts/setup.sh --with-rlr). Both engines run with their
default settings unless ``--set FIELD=VALUE`` changes an ``AcousticsConfig`` field for both (for example
``air_absorption=false``, ``wall_transmission_db=inf``, ``rlr_rays=8000``, ``rlr_sh_order=3``), over the
same source and receiver pairs (heading 0, both ears), with the project's own measures on both:

* T20 per octave band 125 Hz - 4 kHz (``acoustics.measure_rt60`` of ``octave_band``, mean of the ears)
* DRR: energy of the direct sound (from 1 ms before the onset to 2.5 ms after it) over the rest, dB
* EDT: the Schroeder curve's fit from 0 to -10 dB, times 6 (broadband, mean of the ears)
* C50: energy in the 50 ms after the onset over the energy after, dB
* ITD (ms, positive: left ear first; the direct sound's cross-correlation) and ILD (dB, left over right)

    python scripts/compare_engines.py --out docs/results/engines [--world test:0|map:PATH/map.yaml] [--sources 2]
                                      [--set FIELD=VALUE ...]

Writes pairs.csv (one row per pair and engine) and summary.md (medians per engine and of the paired
differences, over all pairs, the pairs within one room and those across rooms, with the command); prints it.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import difflib
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from m2h_ros.core.world.acoustics import (
    BAND_CENTRES,
    BACKENDS,
    AcousticsConfig,
    assemble,
    measure_rt60,
    octave_band,
    receiver_positions,
    simulate_source,
)
from m2h_ros.core.world.scene import SCENE_SPLITS, load_split
from m2h_ros.core.world.worlds import is_world_spec, load_world
from m2h_ros.errors import ConfigError, reports_errors

BANDS = BAND_CENTRES[BAND_CENTRES <= 4000]  # 8 kHz is the Nyquist frequency at 16 kHz


def _onset(rir: np.ndarray) -> int:
    envelope = np.abs(rir).max(axis=0)
    return int(np.argmax(envelope >= 0.2 * envelope.max()))


def _decay_curve(signal: np.ndarray) -> np.ndarray:
    energy = np.cumsum(signal[::-1] ** 2)[::-1]
    return 10 * np.log10(energy / energy[0] + 1e-300)


def _edt(signal: np.ndarray, rate: int) -> float:
    curve = _decay_curve(signal)
    stop = int(np.argmax(curve <= -10.0))
    slope = np.polyfit(np.arange(stop) / rate, curve[:stop], 1)[0]
    return float(-60.0 / slope)


def measures(rir: np.ndarray, rate: int) -> dict[str, float]:
    """The side-by-side measures of one binaural RIR (2, T), float64."""
    onset = _onset(rir)
    lo, hi = max(0, onset - rate // 1000), onset + int(0.0025 * rate)
    direct = rir[:, lo:hi]
    energy = (rir ** 2).sum()
    direct_energy = (direct ** 2).sum()
    early = (rir[:, lo: onset + int(0.05 * rate)] ** 2).sum()
    xcorr = np.correlate(np.repeat(direct[1], 8), np.repeat(direct[0], 8), mode="full")
    out = {
        "drr_db": 10 * np.log10(direct_energy / (energy - direct_energy)),
        "edt_s": float(np.mean([_edt(ear[onset:], rate) for ear in rir])),
        "c50_db": 10 * np.log10(early / (energy - early)),
        "itd_ms": (np.argmax(xcorr) - (8 * direct.shape[1] - 1)) / (8 * rate) * 1e3,
        "ild_db": 10 * np.log10((direct[0] ** 2).sum() / (direct[1] ** 2).sum()),
    }
    for centre in BANDS:
        out[f"t20_{int(centre)}_s"] = float(np.mean([measure_rt60(octave_band(ear, centre, rate), rate)
                                                     for ear in rir]))
    return out


def pairs(scene, config: AcousticsConfig, *, sources: int, receivers: int, min_distance: float) -> list:
    """(source node, [receiver nodes]) spread over the scene, receivers at least ``min_distance`` away."""
    points = receiver_positions(scene, config)
    chosen = []
    for source in np.linspace(0, len(points) - 1, sources).astype(int):
        far = np.flatnonzero(np.linalg.norm(points - points[source], axis=1) >= min_distance)
        chosen.append((int(source), far[np.linspace(0, len(far) - 1, min(receivers, len(far))).astype(int)]))
    return chosen


def summary(rows: list[dict], keys: list[str]) -> str:
    by = {b: {(r["source"], r["receiver"]): r for r in rows if r["backend"] == b} for b in BACKENDS}
    common = sorted(set(by["project"]) & set(by["rlr"]))
    if not common:
        return "No such pairs.\n"
    lines = ["| measure | project (median) | rlr (median) | rlr - project, paired (median [IQR]) |",
             "| --- | --- | --- | --- |"]
    for key in keys:
        project = np.array([by["project"][p][key] for p in common])
        rlr = np.array([by["rlr"][p][key] for p in common])
        diff = rlr - project
        q1, q3 = np.percentile(diff, [25, 75])
        lines.append(f"| {key} | {np.median(project):.3f} | {np.median(rlr):.3f} | "
                     f"{np.median(diff):+.3f} [{q1:+.3f}, {q3:+.3f}] |")
    return "\n".join(lines) + f"\n\n{len(common)} source-receiver pairs, heading 0.\n"


def config_overrides(items: list[str]) -> dict[str, object]:
    """``FIELD=VALUE`` strings as AcousticsConfig fields; values read as YAML ("inf" as infinity)."""
    fields = {f.name for f in dataclasses.fields(AcousticsConfig)} - {"backend", "rlr_threads"}
    settings = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or name not in fields:
            close = difflib.get_close_matches(name, sorted(fields), n=1)
            raise ConfigError(f"--set {item!r} must be FIELD=VALUE with FIELD an AcousticsConfig setting"
                              + (f" (did you mean {close[0]!r}?)" if close else f": {', '.join(sorted(fields))}"))
        value = yaml.safe_load(text)
        settings[name] = float(value) if isinstance(value, str) and value.lower() in ("inf", "+inf") else value
    return settings


@reports_errors("compare_engines")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="results folder to write")
    parser.add_argument("--world", default="test:0", help="SPLIT:INDEX of a generated scene (default test:0), "
                        "or an imported world: map:PATH/map.yaml, mesh:PATH")
    parser.add_argument("--sources", type=int, default=2)
    parser.add_argument("--receivers", type=int, default=6, help="receivers per source")
    parser.add_argument("--min-distance", type=float, default=1.5, help="m between source and receiver")
    parser.add_argument("--threads", type=int, default=1, help="the rlr engine's threads")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="an AcousticsConfig field for both engines (repeatable), e.g. air_absorption=false")
    args = parser.parse_args(argv)
    settings = config_overrides(args.set)
    split, _, index = args.world.partition(":")
    if is_world_spec(args.world):
        scene = load_world(args.world)
    elif split in SCENE_SPLITS and index.isdigit():
        scene = load_split(split)[int(index)]
    else:
        raise ConfigError(f"--world {args.world!r} must be SPLIT:INDEX with SPLIT one of {sorted(SCENE_SPLITS)}, "
                          f"map:PATH/map.yaml or mesh:PATH")
    rows, seconds = [], {}
    for backend in BACKENDS:
        config = AcousticsConfig(**{**settings, "backend": backend, "rlr_threads": args.threads})
        start = time.perf_counter()
        for source, receivers in pairs(scene, config, sources=args.sources, receivers=args.receivers,
                                       min_distance=args.min_distance):
            bank_rows = simulate_source(scene, source, config)
            rirs = assemble(np.asarray(bank_rows[receivers]), np.zeros(len(receivers), int), config)
            for receiver, rir in zip(receivers, rirs):
                same_room = bool(scene.grid.room_of[receiver] == scene.grid.room_of[source])
                rows.append({"backend": backend, "source": source, "receiver": int(receiver), "same_room": same_room,
                             **measures(rir.astype(np.float64), config.sample_rate)})
        seconds[backend] = time.perf_counter() - start
        print(f"{backend}: {seconds[backend]:.0f} s for {args.sources} source nodes", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    keys = [k for k in rows[0] if k not in ("backend", "source", "receiver", "same_room")]
    tables = (f"All pairs:\n\n{summary(rows, keys)}\nSource and receiver in the same room (a line of sight):\n\n"
              f"{summary([r for r in rows if r['same_room']], keys)}\nIn different rooms (through doors and walls):"
              f"\n\n{summary([r for r in rows if not r['same_room']], keys)}")
    with open(args.out / "pairs.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows({k: (f"{v:.5g}" if isinstance(v, float) else v) for k, v in row.items()} for row in rows)
    command = "python scripts/compare_engines.py " + " ".join(sys.argv[1:] if argv is None else argv)
    text = (f"# The two engines side by side: scene {scene.scene_id}\n\n`{command}`\n\n"
            f"Date: {time.strftime('%Y-%m-%d')}\n\n{tables}\n"
            f"Wall time of the renders: " + ", ".join(f"{b} {s:.0f} s" for b, s in seconds.items()) + ".\n")
    (args.out / "summary.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
