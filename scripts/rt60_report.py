"""RT60 of the default scenes per octave band: Eyring for every room, and measured (Schroeder T20).

    python scripts/rt60_report.py [--splits train val test] [--measure test [val ...]]
                                  [--where scene isolated] [--sources 2] [--png rt60.png]

Eyring: ``room_rt60`` of every room of the given splits (analytic, instant). Measured: the
median T20 of RIRs inside each room of the ``--measure`` splits' scenes, simulated by the bank's
code path (``measured_room_rt60``; a few seconds per source node), ``--where``: in the scene, where
rooms are coupled through their doors, and/or each room on its own (doors shut), the closed room
that Eyring's formula describes. Rooms without two free nodes 1.5 m apart are skipped.
"""

from __future__ import annotations

import argparse
import time
import sys

import numpy as np

from m2h_ros.core.plotting import agg_pyplot
from m2h_ros.core.world.acoustics import BAND_CENTRES, AcousticsConfig, measured_room_rt60, room_rt60
from m2h_ros.core.world.scene import SCENE_SPLITS, isolated_room, load_split
from m2h_ros.errors import ConfigError, reports_errors

SHOWN = BAND_CENTRES <= 4000  # the 8 kHz octave is cut by the 16 kHz sampling rate


def _summary(name: str, rt60: np.ndarray) -> None:
    print(f"{name} ({len(rt60)} rooms): 10th percentile / median / 90th percentile (s), share in 0.3-0.8 s")
    for band, centre in enumerate(BAND_CENTRES[SHOWN]):
        values = rt60[:, band]
        p10, p50, p90 = np.percentile(values, [10, 50, 90])
        inside = np.mean((values >= 0.3) & (values <= 0.8))
        print(f"  {centre:6.0f} Hz  {p10:5.2f} / {p50:5.2f} / {p90:5.2f}   {inside:4.0%}   max {values.max():5.2f}")


def _ratios(name: str, measured: np.ndarray, eyring: np.ndarray, rooms: list[str]) -> None:
    ratio = measured / eyring
    outside = np.abs(ratio - 1) > 0.2
    print(f"{name} / Eyring: median [min, max] per band; {len(ratio) - outside.any(axis=1).sum()} of "
          f"{len(ratio)} rooms within 20% in every band")
    for band, centre in enumerate(BAND_CENTRES[SHOWN]):
        r = ratio[:, band]
        print(f"  {centre:6.0f} Hz  {np.median(r):4.2f} [{r.min():4.2f}, {r.max():4.2f}]")
    for k in np.flatnonzero(outside.any(axis=1)):
        bands = ", ".join(f"{centre:.0f} Hz {ratio[k, band]:.2f}"
                          for band, centre in enumerate(BAND_CENTRES[SHOWN]) if outside[k, band])
        print(f"  outside 20%: {rooms[k]}: {bands}")


@reports_errors("rt60_report")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--splits", nargs="+", choices=sorted(SCENE_SPLITS), default=list(SCENE_SPLITS))
    parser.add_argument("--measure", nargs="+", choices=sorted(SCENE_SPLITS), default=[],
                        help="splits whose rooms are simulated")
    parser.add_argument("--where", nargs="+", choices=("scene", "isolated"), default=["scene", "isolated"])
    parser.add_argument("--sources", type=int, default=2, help="source nodes per room")
    parser.add_argument("--png", help="write box plots of the RT60s per band here")
    args = parser.parse_args(argv)

    config = AcousticsConfig()
    print(f"RIR length {config.rir_length} s")
    eyring = np.array([room_rt60(scene, i)[SHOWN] for split in args.splits for scene in load_split(split)
                       for i in range(len(scene.rooms))])
    _summary(f"Eyring, splits {' '.join(args.splits)}", eyring)
    series = {"Eyring": eyring}
    if args.measure:
        start = time.perf_counter()
        for where in args.where:
            eyring_rows, measured_rows, rooms = [], [], []
            for scene in (scene for split in args.measure for scene in load_split(split)):
                for index in range(len(scene.rooms)):
                    room, room_index = (scene, index) if where == "scene" else (isolated_room(scene, index), 0)
                    try:
                        measured = measured_room_rt60(room, room_index, config, n_sources=args.sources)
                    except ConfigError as err:  # too small a room for a source-receiver pair
                        print(f"  skipped: {err}")
                        continue
                    measured_rows.append(measured[SHOWN])
                    eyring_rows.append(room_rt60(room, room_index)[SHOWN])
                    rooms.append(f"{scene.scene_id} room {index} ({scene.rooms[index].area:.1f} m^2)")
            name = f"measured {'in scene' if where == 'scene' else 'isolated'}, {' '.join(args.measure)}"
            _summary(name, np.array(measured_rows))
            _ratios(name, np.array(measured_rows), np.array(eyring_rows), rooms)
            series[name] = np.array(measured_rows)
        print(f"simulated in {time.perf_counter() - start:.0f} s")
    if args.png:
        _plot(series, args.png)
        print(f"wrote {args.png}")


def _plot(series: dict[str, np.ndarray], path: str) -> None:
    plt = agg_pyplot()
    fig, ax = plt.subplots(figsize=(8, 4))
    centres = np.arange(int(SHOWN.sum()))
    width = 0.8 / len(series)
    for k, (name, values) in enumerate(series.items()):
        ax.boxplot(values, positions=centres + (k - (len(series) - 1) / 2) * width, widths=width * 0.9,
                   patch_artist=True, boxprops={"facecolor": f"C{k}"}, label=name)
    ax.axhspan(0.3, 0.8, color="0.9", zorder=0)
    ax.set_xticks(centres, [f"{c:.0f}" for c in BAND_CENTRES[SHOWN]])
    ax.set_xlabel("octave band (Hz)")
    ax.set_ylabel("RT60 (s)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
