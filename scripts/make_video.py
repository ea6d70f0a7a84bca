#!/usr/bin/env python3
"""Turn a recorded episode into an MP4 with sound, as the paper's supplementary video shows a run.

    python scripts/make_video.py runs/demo                  # the run's first episode
    python scripts/make_video.py runs/demo/bag --episode 2 --out demo.mp4 --size 480x270

One picture per step (map with path and sources, camera, spectrograms of the mixture and of the separated
estimate, SI-SDR curve), shown for the step's 1 s of audio; two AAC audio streams: the binaural mixture
(stream 1, played by default) and the separated estimate (stream 2: in VLC, Audio > Audio Track; in mpv,
the # key). Encoded by the ffmpeg that imageio-ffmpeg ships.
"""

import argparse
import sys
from pathlib import Path

from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.video import make_video, read_episode, write_still


def size(text: str) -> tuple[int, int]:
    width, _, height = text.partition("x")
    try:
        return int(width), int(height)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT") from None


@reports_errors("make_video")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a run directory (with bag/) or a bag directory")
    parser.add_argument("--episode", default="0", help="episode number in the bag (from 0) or episode id")
    parser.add_argument("--out", type=Path, default=None, help="MP4 file (default RUN/videos/<episode>.mp4)")
    parser.add_argument("--size", type=size, default=(640, 360), help="WIDTHxHEIGHT, even (default 640x360)")
    parser.add_argument("--fps", type=int, default=4, help="frame rate of the file (pictures change per step)")
    parser.add_argument("--audio-kbps", type=int, default=32, help="AAC bit rate of each audio stream")
    parser.add_argument("--still", type=Path, default=None, help="also write one step's picture as this PNG")
    parser.add_argument("--still-step", type=int, default=None, help="the step --still shows (default: the middle)")
    args = parser.parse_args(argv)
    bag = args.run / "bag" if (args.run / "bag" / "metadata.yaml").exists() else args.run
    if not (bag / "metadata.yaml").exists():
        raise ConfigError(f"{args.run} is neither a run directory with bag/ nor a bag directory")
    media = read_episode(bag, int(args.episode) if args.episode.isdigit() else args.episode)
    out = args.out or bag.parent / "videos" / f"{media.episode_id.replace('/', '_')}.mp4"
    width, height = args.size
    make_video(media, out, width=width, height=height, fps=args.fps, audio_kbps=args.audio_kbps)
    if args.still:
        step = media.steps[len(media.steps) // 2] if args.still_step is None else args.still_step
        print(f"{write_still(media, args.still, step=step, width=width, height=height)}: step {step}")
    print(f"{out}: {len(media.steps)} steps, {out.stat().st_size / 1e6:.2f} MB; audio stream 1 the mixture, "
          f"stream 2 the separated estimate")
    return 0


if __name__ == "__main__":
    sys.exit(main())
