"""scripts/make_video.py turns a recorded episode into an MP4 that another decoder (PyAV) reads back: one
picture per step shown for the step's audio, and two AAC streams that carry the bag's mixture (binaural)
and the bag's separated estimate."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest
from matplotlib.image import imread
from scipy.signal import correlate

from m2h_ros import topics
from m2h_ros.io.bag import BagWriter, read_messages
from m2h_ros.io.synthetic import STEP_NS, SyntheticRun, write_synthetic_run
from m2h_ros.video import STREAM_TITLES, read_episode

ROOT = Path(__file__).resolve().parents[1]
STEPS = 6  # observations of the episode: max_steps + 1
FPS = 4


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    run = tmp_path_factory.mktemp("run")
    with BagWriter(run / "bag") as writer:
        write_scene(writer, stamp_ns=10**18)  # before the episodes: the plan they play in
        write_synthetic_run(run / "bag", SyntheticRun(episodes=2, max_steps=STEPS - 1), writer=writer)
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_video.py"), str(run), "--episode", "1",
                             "--size", "320x180", "--fps", str(FPS), "--audio-kbps", "128",
                             "--still", str(run / "still.png"), "--still-step", "2"], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    return run, run / "videos" / "test_near_target_heard_000001.mp4"


GRID = np.zeros((8, 10), np.int8)
GRID[0, :] = 100  # a wall along the bottom row
SOURCES = [((2.0, 3.0), "target: speech"), ((6.5, 1.5), "distractor: music")]


def write_scene(writer: BagWriter, *, stamp_ns: int) -> None:
    """A floor plan and source markers as the simulator publishes them (a label above each ball)."""
    from nav_msgs.msg import OccupancyGrid
    from rclpy.serialization import serialize_message
    from visualization_msgs.msg import Marker, MarkerArray

    grid = OccupancyGrid()
    grid.header.stamp.sec, grid.header.frame_id = stamp_ns // 10**9, "map"
    grid.info.resolution, grid.info.width, grid.info.height = 0.5, 10, 8
    grid.info.origin.position.x, grid.info.origin.position.y = -1.0, -0.5
    grid.data = GRID.ravel().tolist()
    writer.write_raw("/map", "nav_msgs/msg/OccupancyGrid", stamp_ns, serialize_message(grid))
    markers = [Marker(header=grid.header, action=Marker.DELETEALL)]  # the previous episode's
    for k, ((x, y), label) in enumerate(SOURCES):
        for kind, text in ((Marker.SPHERE, ""), (Marker.TEXT_VIEW_FACING, label)):
            marker = Marker(header=grid.header, ns="sources", id=k, type=kind, action=Marker.ADD, text=text)
            marker.pose.position.x, marker.pose.position.y = x, y
            markers.append(marker)
    writer.write_raw("/ground_truth/sources", "visualization_msgs/msg/MarkerArray", stamp_ns,
                     serialize_message(MarkerArray(markers=markers)))


def bag_audio(bag: Path, topic: str, episode_id: str) -> np.ndarray:
    """The episode's audio on ``topic``, steps end to end: (channels, samples)."""
    steps = sorted((m.message.step, np.asarray(m.message.samples, np.float32).reshape(m.message.channels, -1))
                   for m in read_messages(bag, topics=[topic]) if m.message.episode_id == episode_id)
    return np.concatenate([samples for _, samples in steps], axis=1)


def decoded_audio(container, stream) -> np.ndarray:
    return np.concatenate([frame.to_ndarray() for frame in container.decode(stream)], axis=1)


def best_correlation(a: np.ndarray, b: np.ndarray, max_lag: int = 4096) -> float:
    """Normalised correlation of two signals at the lag (up to ``max_lag`` samples) that aligns them best
    (an AAC decoder may keep some of its encoder's start-up delay)."""
    full = correlate(a, b, mode="full", method="fft")
    zero = len(b) - 1
    lag = int(np.argmax(full[zero - max_lag: zero + max_lag + 1])) - max_lag
    x, y = (a[lag:], b) if lag >= 0 else (a, b[-lag:])
    n = min(len(x), len(y))
    return float(np.corrcoef(x[:n], y[:n])[0, 1])


def test_the_video_shows_each_step_for_its_audio(video):
    _, path = video
    with av.open(str(path)) as container:
        (picture,) = container.streams.video
        assert (picture.codec_context.name, picture.width, picture.height) == ("h264", 320, 180)
        frames = sum(1 for _ in container.decode(picture))
    assert frames == STEPS * FPS
    assert float(picture.duration * picture.time_base) == pytest.approx(STEPS, abs=0.3)


def test_both_audio_streams_carry_the_bags_audio(video):
    run, path = video
    episode_id = "test/near_target/heard/000001"
    mixture = bag_audio(run / "bag", "/" + topics.AUDIO, episode_id)
    estimate = bag_audio(run / "bag", "/" + topics.SEPARATED_AUDIO, episode_id)
    with av.open(str(path)) as container:
        first, second = container.streams.audio
        assert [first.metadata.get("name"), second.metadata.get("name")] == list(STREAM_TITLES)
        assert (first.channels, second.channels, first.sample_rate) == (2, 1, 16000)
        heard = decoded_audio(container, first)
    with av.open(str(path)) as container:
        separated = decoded_audio(container, container.streams.audio[1])
    assert abs(heard.shape[1] - mixture.shape[1]) < 2048 and float(np.abs(heard).max()) < 1.0
    for ear in range(2):
        assert best_correlation(heard[ear], mixture[ear]) > 0.98, ear
    assert best_correlation(separated[0], estimate[0]) > 0.98


def test_the_map_and_the_sources_come_from_the_bag(video):
    run, _ = video
    media = read_episode(run / "bag", 1)
    occupancy, extent, yaw = media.grid
    assert np.array_equal(occupancy, GRID) and extent == (-1.0, 4.0, -0.5, 3.5) and yaw == 0.0
    assert media.sources == [(x, y, label) for (x, y), label in SOURCES]
    assert sorted(media.pose) == list(range(STEPS))


def test_the_still_is_its_steps_picture(video):
    run, path = video
    still = imread(run / "still.png")[..., :3] * 255.0
    assert still.shape == (180, 320, 3)
    with av.open(str(path)) as container:
        pictures = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)][::FPS]
    distance = [float(np.abs(picture - still).mean()) for picture in pictures]
    assert int(np.argmin(distance)) == 2, distance


def test_an_unknown_episode_is_named(video):
    run, _ = video
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_video.py"), str(run), "--episode", "7"],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 2
    assert "make_video: error: episode 7 is not in" in result.stderr and "(2 episodes)" in result.stderr


def test_a_missing_encoder_is_named(video, tmp_path):
    run, _ = video
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_video.py"), str(run), "--out",
                             str(tmp_path / "x.mp4")], capture_output=True, text=True, cwd=ROOT,
                            env={**os.environ, "IMAGEIO_FFMPEG_EXE": str(tmp_path / "no_ffmpeg")})
    assert result.returncode == 2
    assert "make_video: error: cannot run ffmpeg" in result.stderr and "no_ffmpeg" in result.stderr


class LateEpisodeInfo(BagWriter):
    """Logs each EpisodeInfo after its episode's first step, as a busy recorder can."""

    def write(self, topic, msgtype, timestamp, message):
        super().write(topic, msgtype, timestamp + (3 * STEP_NS // 2 if topic == "/episode" else 0), message)


def test_steps_logged_before_their_episode_info_are_kept(tmp_path):
    with LateEpisodeInfo(tmp_path / "bag") as writer:
        write_synthetic_run(tmp_path / "bag", SyntheticRun(episodes=2, max_steps=STEPS - 1), writer=writer)
    media = read_episode(tmp_path / "bag", 1)
    assert media.steps == list(range(STEPS)) and sorted(media.pose) == list(range(STEPS))
    assert media.title.startswith("near-target: speech target vs music")
