"""A video of one recorded episode, as the paper's supplementary video shows a run: the top-down map with
the robot's path and the sources, the camera, the mixture's and the separated estimate's spectrograms and
the SI-SDR curve, one picture per step; with sound, as two audio streams the viewer switches between:
the binaural mixture the robot heard (stream 1, the default) and the separated estimate (stream 2).

Everything comes from the bag (the map and the sources where the run recorded them); ffmpeg (the build
imageio-ffmpeg ships) encodes H.264 and AAC. ROS-free."""

from __future__ import annotations

import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import soundfile

from m2h_ros import topics
from m2h_ros.core.audio.stft import log_magnitude, stft
from m2h_ros.errors import BagError, ConfigError, VideoError
from m2h_ros.io.bag import read_messages

STREAM_TITLES = ("mixture (binaural, as heard)", "separated estimate")
PEAK = 0.9  # each stream is scaled so its loudest sample sits here: the two are heard at a like level
MAP_TOPIC, SOURCES_TOPIC = "/map", "/ground_truth/sources"  # where a run records its scene
ADD, TEXT_VIEW_FACING = 0, 9  # visualization_msgs/Marker's action and type constants


def absolute(name: str) -> str:
    return name if name.startswith("/") else "/" + name


@dataclass
class EpisodeMedia:
    """What one episode's video shows, per step (the step index keys every dict)."""

    episode_id: str
    title: str
    sample_rate: int
    step_samples: int  # audio samples per step (the simulator's clip length)
    mixture: dict[int, np.ndarray] = field(default_factory=dict)  # (channels, step_samples)
    estimate: dict[int, np.ndarray] = field(default_factory=dict)  # (step_samples,)
    camera: dict[int, np.ndarray] = field(default_factory=dict)  # (h, w, 3) uint8
    si_sdr: dict[int, float] = field(default_factory=dict)  # dB
    pose: dict[int, tuple[float, float, float]] = field(default_factory=dict)  # x, y, yaw in the map frame
    grid: tuple[np.ndarray, tuple[float, float, float, float], float] | None = None  # occupancy, extent, yaw
    sources: list[tuple[float, float, str]] = field(default_factory=list)  # x, y, label (target first)

    @property
    def steps(self) -> list[int]:
        return sorted(self.mixture)

    def track(self, which: str) -> np.ndarray:
        """The episode's ``mixture`` (channels, n) or ``estimate`` (1, n) audio, steps end to end (a step
        without an estimate is silent), scaled to PEAK."""
        parts = []
        for step in self.steps:
            if which == "mixture":
                parts.append(self.mixture[step])
            else:
                parts.append(self.estimate.get(step, np.zeros(self.step_samples, np.float32))[None])
        audio = np.concatenate(parts, axis=1).astype(np.float32)
        peak = float(np.abs(audio).max())
        return audio * (PEAK / peak) if peak > 0 else audio


def episode_ids(bag: Path) -> list[str]:
    """The episodes of a bag, in the order they were played."""
    return [m.message.episode_id for m in read_messages(bag, topics=[absolute(topics.EPISODE)])]


def read_episode(bag: Path, episode: int | str = 0) -> EpisodeMedia:
    """Episode number ``episode`` (or the one with that id) of the bag at ``bag``."""
    ids = episode_ids(bag)
    if isinstance(episode, int):
        if not 0 <= episode < len(ids):
            raise ConfigError(f"episode {episode} is not in {bag} ({len(ids)} episodes)")
        episode = ids[episode]
    elif episode not in ids:
        raise ConfigError(f"episode {episode!r} is not in {bag}; it holds {', '.join(ids) or 'none'}")
    wanted = [absolute(t) for t in (topics.EPISODE, topics.AUDIO, topics.SEPARATED_AUDIO, topics.STEP_SCORE,
                                    topics.AGENT_POSE, topics.RGB)] + [MAP_TOPIC, SOURCES_TOPIC]
    media = EpisodeMedia(episode, episode, 0, 0)  # messages of a step may be logged before its EpisodeInfo
    step_of: dict[int, int] = {}  # stamp (ns) -> step: images and scene messages carry only their stamp
    stamped: list[tuple[str, int, object]] = []
    for item in read_messages(bag, topics=wanted):
        msg, topic = item.message, item.topic
        if topic in (MAP_TOPIC, SOURCES_TOPIC, absolute(topics.RGB)):
            header = msg.markers[0].header if topic == SOURCES_TOPIC and msg.markers else getattr(msg, "header", None)
            if header is not None:  # a MarkerArray's stamp is its markers'
                stamped.append((topic, header.stamp.sec * 10**9 + header.stamp.nanosec, msg))
            continue
        if getattr(msg, "episode_id", None) != episode:
            continue
        if topic == absolute(topics.EPISODE):
            media.title = (f"{msg.task.replace('_', '-')}: {msg.target_class} target vs "
                           f"{', '.join(msg.source_classes[1:])} ({msg.episode_id})")
        elif topic == absolute(topics.AUDIO):
            samples = np.asarray(msg.samples, np.float32).reshape(msg.channels, -1)
            media.sample_rate, media.step_samples = int(msg.sample_rate), samples.shape[1]
            media.mixture[msg.step] = samples
            step_of[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = msg.step
        elif topic == absolute(topics.SEPARATED_AUDIO):
            # one track: a binaural estimate plays as its ear mean
            media.estimate[msg.step] = np.asarray(msg.samples, np.float32).reshape(max(msg.channels, 1), -1).mean(axis=0)
        elif topic == absolute(topics.STEP_SCORE):
            media.si_sdr[msg.step] = float(msg.si_sdr)
        elif topic == absolute(topics.AGENT_POSE):
            p, q = msg.pose.position, msg.pose.orientation
            media.pose[msg.step] = (p.x, p.y, float(np.arctan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))))
    if not media.mixture:
        raise BagError(f"{bag}: episode {episode!r} has no audio")
    first = min(step_of)
    for topic, stamp, msg in stamped:
        if topic == absolute(topics.RGB) and stamp in step_of:
            media.camera[step_of[stamp]] = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width, -1)[..., :3]
        elif topic == MAP_TOPIC and stamp <= first:  # the latest plan published by the episode's start
            info = msg.info
            x0, y0 = info.origin.position.x, info.origin.position.y
            extent = (x0, x0 + info.width * info.resolution, y0, y0 + info.height * info.resolution)
            yaw = 2 * np.arctan2(info.origin.orientation.z, info.origin.orientation.w)  # a map turned in its frame
            media.grid = (np.asarray(msg.data, np.int8).reshape(info.height, info.width), extent, float(yaw))
        elif topic == SOURCES_TOPIC and stamp <= first:  # a ball per source (id 0: the target), a label each
            labels = {m.id: m.text for m in msg.markers if m.action == ADD and m.type == TEXT_VIEW_FACING}
            media.sources = [(m.pose.position.x, m.pose.position.y, labels.get(m.id, ""))
                             for m in sorted(msg.markers, key=lambda m: m.id)
                             if m.action == ADD and m.type != TEXT_VIEW_FACING]
    return media


def render_frames(media: EpisodeMedia, *, width: int, height: int, only: int | None = None):
    """One RGB picture (height, width, 3) uint8 per step (or only the step ``only``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
    from matplotlib.figure import Figure  # noqa: PLC0415

    steps = media.steps
    scores = [media.si_sdr.get(s, np.nan) for s in steps]
    path = np.array([media.pose[s][:2] for s in steps if s in media.pose]).reshape(-1, 2)
    spectra = {s: (log_magnitude(stft(media.mixture[s].mean(axis=0))),
                   log_magnitude(stft(media.estimate[s])) if s in media.estimate else None) for s in steps}
    vmax = max(float(np.percentile(m, 99.5)) for m, _ in spectra.values())
    for k, step in enumerate(steps):
        if only is not None and step != only:
            continue
        fig = Figure(figsize=(width / 100, height / 100), dpi=100)
        grid = fig.add_gridspec(2, 3, width_ratios=[1.15, 1, 1], left=0.04, right=0.99, bottom=0.1, top=0.86,
                                wspace=0.28, hspace=0.45)
        fig.suptitle(f"{media.title}\nstep {step} of {steps[-1]}   SI-SDR {scores[k]:+.1f} dB", fontsize=7)
        top = fig.add_subplot(grid[:, 0])
        _draw_map(top, media, path[: k + 1], media.pose.get(step))
        cam = fig.add_subplot(grid[0, 1])
        if step in media.camera:
            cam.imshow(media.camera[step])
        cam.set_title("camera", fontsize=6)
        cam.axis("off")
        curve = fig.add_subplot(grid[1, 1])
        curve.plot(steps, scores, color="#bbbbbb", lw=1)
        curve.plot(steps[: k + 1], scores[: k + 1], color="#d62728", lw=1.5, marker=".", ms=3)
        curve.set_title("SI-SDR of the estimate (dB)", fontsize=6)
        curve.set_xlabel("step", fontsize=6)
        curve.tick_params(labelsize=5)
        curve.grid(alpha=0.3)
        for row, (name, spec) in enumerate(zip(("mixture", "separated estimate"), spectra[step], strict=True)):
            ax = fig.add_subplot(grid[row, 2])
            if spec is not None:
                ax.imshow(spec, origin="lower", aspect="auto", cmap="magma", vmin=0, vmax=vmax,
                          extent=(0, media.step_samples / media.sample_rate, 0, media.sample_rate / 2000))
            ax.set_title(f"{name} (kHz over s)", fontsize=6)
            ax.tick_params(labelsize=5)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        yield np.asarray(canvas.buffer_rgba())[..., :3].copy()


def _draw_map(ax, media: EpisodeMedia, path: np.ndarray, pose) -> None:
    if media.grid is not None:
        from matplotlib.transforms import Affine2D

        occupancy, extent, yaw = media.grid
        shade = np.where(occupancy < 0, 0.85, 1.0 - np.clip(occupancy, 0, 100) / 100 * 0.8)
        image = ax.imshow(shade, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        if yaw:
            image.set_transform(Affine2D().rotate_around(extent[0], extent[2], yaw) + ax.transData)
            corners = Affine2D().rotate_around(extent[0], extent[2], yaw).transform(
                [[extent[0], extent[2]], [extent[1], extent[2]], [extent[0], extent[3]], [extent[1], extent[3]]])
            ax.update_datalim(corners)
            ax.autoscale_view()
    for index, (x, y, label) in enumerate(media.sources):
        ax.scatter(x, y, s=40, marker="*" if index == 0 else "o", color="#d62728" if index == 0 else "#333333",
                   zorder=5, label=label if label else ("target" if index == 0 else "distractor"))
    if len(path):
        ax.plot(path[:, 0], path[:, 1], color="#1f77b4", lw=1.2, zorder=4)
    if pose is not None:
        x, y, yaw = pose
        ax.annotate("", xy=(x + 0.6 * np.cos(yaw), y + 0.6 * np.sin(yaw)), xytext=(x, y), zorder=6,
                    arrowprops=dict(arrowstyle="-|>", color="#1f77b4", lw=1.2))
    if media.sources:
        ax.legend(fontsize=5, loc="upper center", bbox_to_anchor=(0.5, -0.07), ncol=2, frameon=False)  # off the plan
    points = [p[:2] for p in media.sources] + list(path)
    if media.grid is None and points:  # no plan: frame the path and the sources
        lo, hi = np.min(points, axis=0) - 1.5, np.max(points, axis=0) + 1.5
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_title("map: path and sources", fontsize=6)
    ax.tick_params(labelsize=5)


def write_still(media: EpisodeMedia, out: Path, *, step: int, width: int = 640, height: int = 360) -> Path:
    """The picture of one step as a PNG (for documents)."""
    from matplotlib.image import imsave  # noqa: PLC0415

    if step not in media.mixture:
        raise ConfigError(f"step {step} is not in episode {media.episode_id} (steps {media.steps[0]}..{media.steps[-1]})")
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    imsave(out, next(render_frames(media, width=width, height=height, only=step)))
    return Path(out)


def ffmpeg_exe() -> str:
    """The ffmpeg binary imageio-ffmpeg ships (or the one IMAGEIO_FFMPEG_EXE names)."""
    try:
        import imageio_ffmpeg  # noqa: PLC0415

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError) as exc:
        raise VideoError(f"no ffmpeg: {exc} (scripts/setup.sh installs imageio-ffmpeg, which ships one)") from exc


def make_video(media: EpisodeMedia, out: Path, *, width: int = 640, height: int = 360, fps: int = 4,
               crf: int = 32, audio_kbps: int = 32) -> Path:
    """Write ``media`` as an MP4: H.264 (one picture per step, shown for the step's audio), AAC streams of
    the mixture and the separated estimate, titled; returns ``out``."""
    if width % 2 or height % 2:
        raise ConfigError(f"video size {width}x{height} must be even (H.264's 4:2:0 colour)")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    step_s = media.step_samples / media.sample_rate
    with tempfile.TemporaryDirectory() as tmp:
        tracks = []
        for index, which in enumerate(("mixture", "estimate")):
            tracks.append(Path(tmp) / f"{index}.wav")
            soundfile.write(tracks[-1], media.track(which).T, media.sample_rate, subtype="FLOAT")
        command = [ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
                   "-s", f"{width}x{height}", "-framerate", f"{1 / step_s:g}", "-i", "-",
                   *(arg for track in tracks for arg in ("-i", str(track))),
                   "-map", "0:v", "-map", "1:a", "-map", "2:a", "-r", str(fps),
                   "-c:v", "libx264", "-preset", "veryslow", "-tune", "stillimage", "-crf", str(crf),
                   "-pix_fmt", "yuv420p", "-c:a", "aac", "-b:a", f"{audio_kbps}k",
                   "-metadata:s:a:0", f"title={STREAM_TITLES[0]}", "-metadata:s:a:1", f"title={STREAM_TITLES[1]}",
                   "-disposition:a:0", "default", "-disposition:a:1", "0", "-movflags", "+faststart", str(out)]
        try:
            encoder = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        except OSError as exc:
            raise VideoError(f"cannot run ffmpeg {command[0]}: {exc}") from exc
        try:
            for frame in render_frames(media, width=width, height=height):
                encoder.stdin.write(frame.tobytes())
        except BrokenPipeError:
            pass  # ffmpeg stopped: its own message follows
        finally:
            _, err = encoder.communicate()
    if encoder.returncode != 0:
        raise VideoError(f"ffmpeg could not encode {out}: {err.decode(errors='replace').strip()[-400:]}")
    return out
