"""docs/results/ holds current results only, each folder saying what it shows, the command that makes it,
the shipped models it ran with (their sha256, checked against the files) and the date; no model files."""

import hashlib
import re
from pathlib import Path

import pytest

from m2h_ros.paths import REPO_DIR

RESULTS = REPO_DIR / "docs" / "results"
MODELS = REPO_DIR / "m2h_ros" / "models" / "default"
MAX_BYTES = 30_000_000  # the result tables of every folder (episode-level CSVs), plots; no models
MODEL_LINE = re.compile(r"`(m2h_ros/models/default/[\w.-]+)` sha256 `([0-9a-f]{64})`")
READMES = sorted(p for p in RESULTS.rglob("README.md") if p != RESULTS / "README.md")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_results_hold_no_model_files_and_stay_small():
    files = [p for p in RESULTS.rglob("*") if p.is_file()]
    assert not [p for p in files if p.suffix in (".pt", ".pth", ".ckpt", ".onnx")], "model files in docs/results"
    assert sum(p.stat().st_size for p in files) < MAX_BYTES


@pytest.mark.parametrize("readme", READMES, ids=lambda p: p.parent.relative_to(RESULTS).as_posix())
def test_each_result_folder_opens_with_what_how_which_models_and_when(readme):
    text = readme.read_text()
    assert text.startswith("# ")
    assert "What it shows:" in text.split("\n\n")[1], "the first paragraph says what the folder shows"
    assert re.search(r"Command.*:\n\n```\n.+\n```", text, re.S), "a fenced command block"
    assert re.search(r"^Date: \d{4}-\d{2}-\d{2}", text, re.M)
    models = MODEL_LINE.findall(text)
    assert models, "the shipped models it ran with"
    for path, digest in models:
        assert _sha256(REPO_DIR / path) == digest, f"{readme}: {path} is not the file the result was made with"


def test_every_result_is_under_a_readme_and_in_the_index():
    covered = {p.parent for p in READMES}
    for table in RESULTS.rglob("results.md"):
        assert any(folder == table.parent or folder in table.parents for folder in covered), table
    index = (RESULTS / "README.md").read_text()
    for readme in READMES:
        assert f"({readme.relative_to(RESULTS).as_posix()})" in index, f"{readme} is not in docs/results/README.md"


def test_the_shipped_models_are_all_described():
    # Each shipped checkpoint is named by at least one result, so every file's provenance is on record.
    named = {path for readme in READMES for path, _ in MODEL_LINE.findall(readme.read_text())}
    shipped = {p.relative_to(REPO_DIR).as_posix() for p in MODELS.glob("*.pt")}
    assert shipped <= named, f"shipped but in no result: {sorted(shipped - named)}"
