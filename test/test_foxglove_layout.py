"""The shipped Foxglove layout is what scripts/foxglove_layout.py builds with foxglove-sdk's layout types,
and every topic it opens is one a recorded run carries."""

import json
import subprocess
import sys
from pathlib import Path

from m2h_ros import topics
from m2h_ros.io.derived import Derived, absolute

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "params" / "foxglove_layout.json"


def test_the_shipped_layout_is_the_generated_one():
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "foxglove_layout.py"), "--check"],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr


def _panels(node):
    if node.get("type") == "panel":
        yield node
    for item in node.get("items", []):
        yield from _panels(item["content"])


def test_every_panel_opens_a_topic_of_the_run():
    panels = list(_panels(json.loads(LAYOUT.read_text())["content"]))
    assert {p["panelType"] for p in panels} == {"ThreeDee", "Image", "Plot", "Audio"}
    names = [getattr(topics, name) for name in dir(topics) if name.isupper()]
    run_topics = {absolute(n) for n in names if isinstance(n, str)} | set(Derived().topics())
    named = set()
    for panel in panels:
        config = panel["config"]
        named |= set(config.get("topics", {}))
        named |= {config["imageMode"][k] for k in ("imageTopic", "calibrationTopic") if k in config.get("imageMode", {})}
        named |= {series["value"].split(".")[0] for series in config.get("paths", [])}
        named |= {config["topic"]} if "topic" in config else set()
    assert named <= run_topics, named - run_topics
    audio = {p["config"]["topic"] for p in panels if p["panelType"] == "Audio"}
    assert audio == {"/audio/pcm", "/separator/audio/pcm", "/ground_truth/target/pcm"}
