"""Bag writer cost: microseconds per message written through m2h_ros.io.bag.BagWriter (what the recorder
does with each raw message), for small and audio-sized messages, beside a fixed numpy workload timed in
the same run (m2h_ros.machine.reference_seconds) and the load.

    python scripts/bench/bag_write.py [--messages 20000] [--repeats 3]

Each repeat writes a fresh bag to a temporary directory: --messages raw messages of 1 KiB on one topic,
then --messages / 20 of 128 KiB (one step's binaural mixture) on another, closing the bag (summary,
metadata.yaml) inside the timing. The best repeat is reported, per message and as MB/s.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from m2h_ros.io.bag import BagWriter
from m2h_ros.machine import availability_line, load_average, reference_seconds

TOPIC_TYPE = "m2h_msgs/msg/BinauralAudio"  # any registered type: the bytes are written, not decoded


def seconds_to_write(count: int, size: int, repeats: int) -> float:
    payload = bytes(size)
    best = float("inf")
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            with BagWriter(Path(tmp) / "bag") as writer:
                for k in range(count):
                    writer.write_raw("/bench", TOPIC_TYPE, k, payload)
            best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=20000, help="1 KiB messages per bag (and 1/20 as many 128 KiB)")
    parser.add_argument("--repeats", type=int, default=3, help="bags written per case (best reported)")
    args = parser.parse_args()
    print(f"load average before: {load_average()}")
    print(availability_line())
    reference_ms = 1e3 * min(reference_seconds() for _ in range(args.repeats))
    print(f"reference workload: {reference_ms:8.1f} ms")
    for count, size in ((args.messages, 1024), (max(1, args.messages // 20), 128 * 1024)):
        seconds = seconds_to_write(count, size, args.repeats)
        us = 1e6 * seconds / count
        print(f"{size // 1024:>4} KiB messages: {us:8.1f} us/message (1000 messages = {us / reference_ms:.3f} x the reference), "
              f"{count * size / seconds / 1e6:7.1f} MB/s ({count} messages)")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
