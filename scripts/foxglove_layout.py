"""Write the Foxglove layout that opens a run (params/foxglove_layout.json): the 3D view (map, TF, path,
sources), the camera, the spectrograms (mixture, refined estimate, target), the SI-SDR plot and the
audio tracks (mixture, separated estimate, target), built with foxglove-sdk's own layout types.

    python scripts/foxglove_layout.py [--out params/foxglove_layout.json] [--check]

``--check`` exits 1 when the file differs from what this script writes (the test suite runs it).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import foxglove.layouts as fl

from m2h_ros import topics
from m2h_ros.io.derived import PCM_SUFFIX, absolute

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "params" / "foxglove_layout.json"
# Colour scale of the spectrogram pictures (dB re 1 of the STFT magnitude): the pipeline's 1 s clips of
# average power 1.2 have magnitudes of about 25 dB per bin where they sound.
IMAGE_DB_RANGE = (-20.0, 50.0)


def _spectrogram(topic: str, title: str) -> fl.ImagePanel:
    return fl.ImagePanel(title=title, config=fl.ImageConfig(image_mode=fl.ImageModeConfig(
        image_topic=absolute(topic), color_mode="colormap", color_map="turbo",
        min_value=IMAGE_DB_RANGE[0], max_value=IMAGE_DB_RANGE[1])))


def _audio(topic: str, title: str, *, muted: bool) -> fl.AudioPanel:
    return fl.AudioPanel(title=title, config=fl.AudioConfig(topic=absolute(topic) + PCM_SUFFIX, muted=muted))


def _column(*panels, proportions=None) -> fl.SplitContainer:
    proportions = proportions or [1] * len(panels)
    return fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=p, content=panel) for p, panel in zip(proportions, panels, strict=True)])


def layout() -> fl.Layout:
    scene = fl.ThreeDeePanel(title="scene", config=fl.ThreeDeeConfig(
        follow_tf="base_link", follow_mode="follow-position",
        camera_state=fl.ThreeDeeCameraState(distance=14.0, phi=35.0, theta_offset=0.0, perspective=True),
        topics={absolute(topics.MAP): fl.BaseRendererRosOccupancyGridTopicSettings(visible=True, color_mode="map"),
                absolute(topics.PATH): fl.BaseRendererRosMarkerTopicSettings(visible=True),
                topics.SOURCES: fl.BaseRendererRosMarkerTopicSettings(visible=True)}))
    camera = fl.ImagePanel(title="camera", config=fl.ImageConfig(image_mode=fl.ImageModeConfig(
        image_topic=absolute(topics.RGB), calibration_topic=absolute(topics.CAMERA_INFO))))
    score = fl.PlotPanel(title="SI-SDR (dB) per step", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value=f"{absolute(topics.STEP_SCORE)}.si_sdr"),
        fl.PlotSeries(value=f"{absolute(topics.STEP_SCORE)}.si_sdr_mixture_phase")], show_legend=True))
    spectrograms = _column(_spectrogram(topics.MIXTURE_IMAGE, "mixture (dB)"),
                           _spectrogram(topics.REFINED_IMAGE, "refined estimate (dB)"),
                           _spectrogram(topics.TARGET_IMAGE, "target (dB)"))
    audio = _column(_audio(topics.AUDIO, "mixture", muted=True),
                    _audio(topics.SEPARATED_AUDIO, "separated estimate", muted=False),
                    _audio(topics.GROUND_TRUTH, "target", muted=True))
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=2, content=_column(scene, score, proportions=[3, 1])),
        fl.SplitItem(proportion=1, content=_column(camera, audio, proportions=[1, 2])),
        fl.SplitItem(proportion=1, content=spectrograms)]))


def layout_text() -> str:
    return json.dumps(json.loads(layout().to_json()), indent=2) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--check", action="store_true", help="only compare the file with what would be written")
    args = parser.parse_args(argv)
    text = layout_text()
    if args.check:
        current = args.out.read_text() if args.out.exists() else ""
        if current != text:
            print(f"{args.out} is not what scripts/foxglove_layout.py writes: run it", file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
