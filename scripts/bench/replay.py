"""Replay scoring rate (m2h-eval's core) vs a bare rosbags read of the same bag, and its peak memory on
a bag 10x longer.

    python scripts/bench/replay.py [--episodes 4] [--steps 20] [--repeats 3] [--bag PATH] [--processes] [--workers]
                                   [--cold]

Writes a synthetic recorded run (m2h_ros.io.synthetic: every pipeline topic, camera included, arrays of
the pipeline's sizes) of EPISODES x (STEPS + 1) observations and one 10x longer, or uses --bag (then
no memory comparison). Each measurement runs in a fresh process (peak RSS is that process's), the
cases interleaved REPEATS times; the figures are the median and the min-max spread:

* bare read: rosbags' Reader yields every message's raw bytes (no decoding): the floor of any reader;
* bare read + decode: the same, deserialising the topics replay needs (rosbags' typestore);
* replay: :func:`m2h_ros.io.replay.replay_bag` (stream, decode, group, score, compare with live);
* replay 2 procs (``--processes``): the same with ``ReplayConfig(score_processes=2)`` (``m2h-eval`` on two
  cores): this process reads and scores, a child process scores with it; two cores, where the bare read
  uses one (CPU includes the child's);
* 2 bags, 2 procs (``--workers``): the bag and a copy of it replayed at once by
  :func:`m2h_ros.io.replay.replay_bags` with ``workers=2`` (``m2h-eval --workers 2``), two child processes;
  its steps/s count both bags' steps (CPU includes the children's).

``--cold`` drops the page cache before every measurement (root only: it writes /proc/sys/vm/drop_caches), so
each case reads the bag from disk, as a recording scored once after it was written out of memory does; by
default every case after the first reads it from memory, the stricter comparison.

Reports steps/s and MB/s (bag bytes / wall time), CPU ms per step (the process's user + system time:
less sensitive to the machine's load than wall time), minor page faults per step, the replay / bare-read ratios of both (target
>= 0.5), peak RSS for both bag lengths (target: flat), and the load average before and after. Then the
CPU the chunks' CRC-32 checks take, and from one more replay per bag with timers around its parts, where
a replay step's CPU time goes: the bag walk (BagStream), CDR decoding, scoring (``score_magnitude``, of which its FFTs) and the rest
(grouping, stacking, tracking, comparing with live).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def bag_bytes(bag: Path) -> int:
    return sum(f.stat().st_size for f in bag.glob("*.mcap")) if bag.is_dir() else bag.stat().st_size


def _cpu_seconds() -> float:
    """This process's CPU time and that of its children waited for."""
    return sum(u.ru_utime + u.ru_stime for u in map(resource.getrusage, (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)))


def _time_parts() -> dict[str, float]:
    """Wraps the parts of a replay in CPU timers (this process only); returns the running totals."""
    import scipy.fft

    from m2h_ros.io import replay as replay_module
    from m2h_ros.io.mcap_stream import BagStream
    from m2h_ros.io.msg_defs import typestore

    totals = {"walk": 0.0, "decode": 0.0, "score": 0.0, "fft": 0.0}

    def timed(part, function):
        def wrapper(*args, **kwargs):
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                totals[part] += time.process_time() - start
        return wrapper

    walk = BagStream.messages

    def messages(self, **kwargs):
        stream = walk(self, **kwargs)
        while True:
            start = time.process_time()
            message = next(stream, None)
            totals["walk"] += time.process_time() - start
            if message is None:
                return
            yield message

    BagStream.messages = messages
    store = typestore()
    store.deserialize_cdr = timed("decode", store.deserialize_cdr)
    replay_module.score_magnitude = timed("score", replay_module.score_magnitude)
    scipy.fft.rfft, scipy.fft.irfft = timed("fft", scipy.fft.rfft), timed("fft", scipy.fft.irfft)
    return totals


def child(mode: str, bag: Path, *others: Path) -> dict:
    """One measurement in this (fresh) process."""
    from rosbags.rosbag2 import Reader

    from m2h_ros.io.msg_defs import typestore
    from m2h_ros.io.replay import EXPECTED_TYPES, BagReplay, ReplayConfig, replay_bag, replay_bags
    from m2h_ros.machine import peak_rss_mib

    store = typestore()
    wanted = {ReplayConfig().topic(name) for name in EXPECTED_TYPES}
    parts = _time_parts() if mode == "split" else {}
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    start, cpu = time.perf_counter(), _cpu_seconds()
    steps = 0
    if mode in ("replay", "split", PROCESSES):
        replay = replay_bag(bag, config=ReplayConfig(score_processes=2) if mode == PROCESSES else ReplayConfig())
        steps = replay.steps_scored
        assert replay.ok, [str(p) for p in replay.problems] + [str(m) for m in replay.comparison.mismatches]
    elif mode == WORKERS:
        replays = list(replay_bags([bag, *others], workers=2))
        assert all(isinstance(r, BagReplay) and r.ok for r in replays), replays
        steps = sum(r.steps_scored for r in replays)
    else:
        with Reader(bag) as reader:
            for connection, _, data in reader.messages():
                if mode == "bare+decode" and connection.topic in wanted:
                    store.deserialize_cdr(data, connection.msgtype)
                if connection.topic == "/" + "scores/step":
                    steps += 1
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    return {"seconds": seconds, "cpu_seconds": cpu, "steps": steps, "parts": parts, "page_faults": faults,
            # its own peak (ru_maxrss would start at the driver's, carried over exec) or its workers'
            "peak_rss_mb": max(peak_rss_mib(), resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)}


def checksum_costs(bag: Path) -> dict[str, float]:
    """CPU seconds to CRC-32 the bag's bytes with zlib-ng's function (what the walk uses) and the system
    zlib's (what it used before), each the best of 3."""
    import zlib

    from zlib_ng.zlib_ng import crc32

    files = [bag] if bag.is_file() else sorted(bag.glob("*.mcap"))
    blocks = []  # read once, 1 MiB at a time: the bag in memory once, not again as slices
    for path in files:
        with path.open("rb") as stream:
            blocks.extend(iter(lambda stream=stream: stream.read(1 << 20), b""))
    costs = {}
    for name, function in (("zlib-ng", crc32), ("zlib", zlib.crc32)):
        best = float("inf")
        for _ in range(3):
            start = time.process_time()
            for block in blocks:
                function(block)
            best = min(best, time.process_time() - start)
        costs[name] = best
    return costs


WORKERS = "2 bags, 2 procs"
PROCESSES = "replay 2 procs"
DROP_CACHES = Path("/proc/sys/vm/drop_caches")


def drop_page_cache() -> None:
    os.sync()
    DROP_CACHES.write_text("1\n")


def measure(mode: str, bag: Path, *, copy: Path | None = None, cold: bool = False) -> dict:
    """One measurement in a fresh process; ``copy``: the second bag of the WORKERS case."""
    if cold:
        drop_page_cache()
    bags = [str(bag)] + ([str(copy)] if mode == WORKERS else [])
    out = subprocess.run([sys.executable, __file__, "--child", mode, *bags], check=True, capture_output=True,
                         text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def spread(values: list[float], fmt: str = "{:.1f}") -> str:
    return f"{fmt.format(statistics.median(values))} ({fmt.format(min(values))}-{fmt.format(max(values))})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=20, help="max steps per episode (near-target: 20)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bag", type=Path, default=None, help="an existing bag instead of synthetic ones")
    parser.add_argument("--processes", action="store_true",
                        help="also replay with ReplayConfig(score_processes=2) (this process and a child score)")
    parser.add_argument("--workers", action="store_true",
                        help="also replay two copies of the bag at once in two processes (m2h-eval --workers 2)")
    parser.add_argument("--cold", action="store_true",
                        help="drop the page cache before every measurement: read the bag from disk (root only)")
    parser.add_argument("--child", nargs="+", metavar="MODE BAG", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], *map(Path, args.child[1:]))))
        return
    from m2h_ros.machine import availability_line, load_average  # here: the children time their own imports

    if args.cold and not os.access(DROP_CACHES, os.W_OK):
        parser.error(f"--cold needs to write {DROP_CACHES} (root)")

    print(f"load average before: {load_average()} ({os.cpu_count()} CPUs)")
    print(availability_line())
    with tempfile.TemporaryDirectory(prefix="bench_replay_") as tmp:
        bags = {}
        if args.bag:
            bags["given"] = args.bag
        else:
            from m2h_ros.io.synthetic import SyntheticRun, write_synthetic_run

            for name, episodes in (("short", args.episodes), ("10x", 10 * args.episodes)):
                bags[name] = Path(tmp) / name
                start = time.perf_counter()
                write_synthetic_run(bags[name], SyntheticRun(episodes=episodes, max_steps=args.steps))
                print(f"wrote {name} bag: {episodes} episodes x {args.steps + 1} observations, "
                      f"{bag_bytes(bags[name]) / 1e6:.0f} MB in {time.perf_counter() - start:.1f} s")
        modes = ("bare", "bare+decode", "replay") + ((PROCESSES,) if args.processes else ()) \
            + ((WORKERS,) if args.workers else ())
        # The second bag of the WORKERS case: a copy, so that each process reads its own file.
        copies = {b: shutil.copytree(bag, Path(tmp) / f"{b}_copy") if bag.is_dir()
                  else shutil.copy(bag, Path(tmp) / f"{b}_copy.mcap") for b, bag in bags.items()} if args.workers else {}
        runs = {(b, m): [] for b in bags for m in modes}
        for _ in range(args.repeats):
            for b in bags:
                for m in modes:
                    runs[b, m].append(measure(m, bags[b], copy=copies.get(b), cold=args.cold))
        for b, bag in bags.items():
            size = bag_bytes(bag) / 1e6
            steps = runs[b, "replay"][0]["steps"]
            print(f"\n{b} bag: {size:.0f} MB, {steps} steps scored")
            print(f"  {'case':14s} {'steps/s':>22s} {'MB/s':>22s} {'CPU ms/step':>22s} {'page faults/step':>18s} "
                  f"{'peak RSS MB':>22s}")
            for m in modes:
                secs = [r["seconds"] for r in runs[b, m]]
                cpu = [r["cpu_seconds"] / r["steps"] * 1e3 for r in runs[b, m]]
                faults = [r["page_faults"] / r["steps"] for r in runs[b, m]]
                print(f"  {m:14s} {spread([r['steps'] / s for r, s in zip(runs[b, m], secs, strict=True)]):>22s} "
                      f"{spread([size * r['steps'] / steps / s for r, s in zip(runs[b, m], secs, strict=True)]):>22s} "
                      f"{spread(cpu, '{:.3f}'):>22s} {spread(faults, '{:.0f}'):>18s} "
                      f"{spread([r['peak_rss_mb'] for r in runs[b, m]]):>22s}")
            for case in (m for m in modes if not m.startswith("bare")):
                for base in ("bare", "bare+decode"):
                    pairs = list(zip(runs[b, base], runs[b, case], strict=True))
                    ratios = [(rep["steps"] / rep["seconds"]) / (ref["steps"] / ref["seconds"]) for ref, rep in pairs]
                    cpu_ratios = [(ref["cpu_seconds"] / ref["steps"]) / (rep["cpu_seconds"] / rep["steps"])
                                  for ref, rep in pairs]
                    print(f"  {case} / {base} rate: {spread(ratios, '{:.2f}')} wall, {spread(cpu_ratios, '{:.2f}')} "
                          f"CPU (per interleaved pair; target vs bare >= 0.5)")
            crc = checksum_costs(bag)
            print(f"  checking the chunks' CRC-32 (the whole file, 1 MiB at a time, as the walk does): zlib-ng "
                  f"{crc['zlib-ng'] / steps * 1e3:.3f} ms per step, the system zlib {crc['zlib'] / steps * 1e3:.3f}")
            split = measure("split", bag)
            cpu = {k: v / steps * 1e3 for k, v in split["parts"].items()}
            rest = split["cpu_seconds"] / steps * 1e3 - cpu["walk"] - cpu["decode"] - cpu["score"]
            print(f"  where a replay step's CPU goes (one timed run, {split['cpu_seconds'] / steps * 1e3:.3f} ms/step): "
                  f"bag walk {cpu['walk']:.3f}, decode {cpu['decode']:.3f}, scoring {cpu['score']:.3f} (its FFTs "
                  f"{cpu['fft']:.3f}), rest {rest:.3f} ms")
            if args.cold:  # the ceiling below compares CPU with a read from memory
                continue
            # What the exact scores' FFTs alone leave of the target (CPU ms per step).
            bare = statistics.median(r["cpu_seconds"] / r["steps"] * 1e3 for r in runs[b, "bare"])
            print(f"  ceiling: one core at most bare / (bare + FFTs) = {bare / (bare + cpu['fft']):.2f} of the bare "
                  f"rate; two cores, all but the walk, decoding and FFTs free, 2 bare / (walk + decode + FFTs) = "
                  f"{2 * bare / (cpu['walk'] + cpu['decode'] + cpu['fft']):.2f}")
        if "10x" in bags:
            short = statistics.median(r["peak_rss_mb"] for r in runs["short", "replay"])
            long = statistics.median(r["peak_rss_mb"] for r in runs["10x", "replay"])
            print(f"\npeak RSS of replay: {short:.0f} MB (short) vs {long:.0f} MB (10x longer): "
                  f"ratio {long / short:.2f} (flat: ~1)")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
