"""Draw, from a recorded run's bag, what rviz's and Foxglove's panels show of one episode, as one PNG: the
map (/map), the robot's path (/path), the sources (/ground_truth/sources) and its pose (/tf), beside the
spectrogram pictures of one step (mixture, refined estimate, target).

    python scripts/view_bag.py RUN/bag [--episode 0] [--step -1] --out scene.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from m2h_ros import topics
from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.io.derived import absolute
from m2h_ros.io.mcap_stream import BagStream
from m2h_ros.io.msg_defs import typestore

PICTURES = ((topics.MIXTURE_IMAGE, "mixture"), (topics.REFINED_IMAGE, "refined estimate"),
            (topics.TARGET_IMAGE, "target"))


def _stamp(msg) -> int:
    header = msg.markers[0].header if hasattr(msg, "markers") else msg.header  # a MarkerArray has none itself
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def episode_messages(bag: Path, episode: int) -> dict[str, list]:
    """The decoded messages of the bag's ``episode``-th episode (by the /episode stamps), per topic."""
    store = typestore()
    wanted = {absolute(t) for t in (topics.EPISODE, topics.MAP, topics.PATH, topics.AGENT_POSE)} | {
        topics.SOURCES} | {absolute(t) for t, _ in PICTURES}
    by_topic: dict[str, list] = {}
    for raw in BagStream(bag).messages(topics=wanted):
        by_topic.setdefault(raw.topic, []).append(store.deserialize_cdr(raw.data, raw.msgtype))
    starts = sorted(_stamp(m) for m in by_topic.get(absolute(topics.EPISODE), []))
    if not 0 <= episode < len(starts):
        raise ConfigError(f"{bag} holds {len(starts)} episode(s); --episode {episode} is not one of them")
    begin, end = starts[episode], starts[episode + 1] if episode + 1 < len(starts) else 2**63
    messages = {t: [m for m in msgs if begin <= _stamp(m) < end] for t, msgs in by_topic.items()}
    if not messages.get(absolute(topics.MAP)):
        raise ConfigError(f"{bag}: episode {episode} has no {absolute(topics.MAP)}, so no floor plan to draw (a robot "
                          f"run's bag has none; scripts/make_video.py shows a robot run)")
    return messages


def draw(messages: dict[str, list], *, step: int, out: Path) -> Path:
    grid = messages[absolute(topics.MAP)][0]
    cells = np.asarray(grid.data, np.int8).reshape(grid.info.height, grid.info.width)
    x0, y0, res = grid.info.origin.position.x, grid.info.origin.position.y, grid.info.resolution
    shade = np.where(cells == 100, 0.15, np.where(cells == 0, 0.95, 0.75))
    fig = Figure(figsize=(10, 4.2), layout="constrained")
    top, *pictures = fig.subplots(1, 1 + len(PICTURES), width_ratios=[3] + [1] * len(PICTURES))
    top.imshow(shade, cmap="gray", vmin=0, vmax=1, origin="lower",
               extent=(x0, x0 + res * cells.shape[1], y0, y0 + res * cells.shape[0]))
    path = messages[absolute(topics.PATH)][-1].markers[0].points
    top.plot([p.x for p in path], [p.y for p in path], "-o", color="#1a66e6", ms=3, lw=1.5, label="path")
    for marker in messages[topics.SOURCES][0].markers:
        if marker.type == 2:  # SPHERE: a source
            colour = (marker.color.r, marker.color.g, marker.color.b)
            top.scatter(marker.pose.position.x, marker.pose.position.y, s=120, color=colour, zorder=3)
        elif marker.type == 9:  # TEXT_VIEW_FACING: its label
            top.annotate(marker.text, (marker.pose.position.x, marker.pose.position.y), fontsize=7,
                         xytext=(4, 6), textcoords="offset points")
    poses = messages[absolute(topics.AGENT_POSE)]
    pose = poses[step].pose
    yaw = 2 * np.arctan2(pose.orientation.z, pose.orientation.w)
    top.arrow(pose.position.x, pose.position.y, 0.6 * np.cos(yaw), 0.6 * np.sin(yaw), width=0.08, color="black")
    top.set_aspect("equal")
    top.set_title(f"/map, /path, {topics.SOURCES}, robot at step {poses[step].step}", fontsize=8)
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    for ax, (topic, title) in zip(pictures, PICTURES, strict=True):
        image = messages[absolute(topic)][step]
        values = np.frombuffer(bytes(image.data), "<f4").reshape(image.height, image.width)
        ax.imshow(values, cmap="turbo", vmin=-20, vmax=50, aspect="auto", extent=(0, 1, 0, 8))
        ax.set_title(title + "\n" + absolute(topic).replace("/spectrogram", "/spectrogram\n"), fontsize=7)
        ax.set_xlabel("s")
    pictures[0].set_ylabel("kHz")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=72)
    return out


@reports_errors("view_bag")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", type=Path)
    parser.add_argument("--episode", type=int, default=0, help="which episode of the bag (0: the first)")
    parser.add_argument("--step", type=int, default=-1, help="the step whose pictures to show (-1: the last)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    print(draw(episode_messages(args.bag, args.episode), step=args.step, out=args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
