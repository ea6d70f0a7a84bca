"""Every figure in docs/results/heads/README.md's tables is the one its JSON files hold."""

import json
import re

import pytest

from m2h_ros.paths import REPO_DIR

FOLDER = REPO_DIR / "docs" / "results" / "heads"
HEADS = {"free field, 0.2 m": "free_field_0.2", "spherical head (SOFA)": "sphere"}
FIGURE = re.compile(r"\*{0,2}([+-]?\d+\.\d+) ± (\d+\.\d+)\*{0,2}")


def results(name: str, kind: str) -> dict:
    return json.loads((FOLDER / f"{name}_{kind}.json").read_text())["results"]


def rows(columns: int) -> list[list[str]]:
    """The README's table rows with this many cells that name a head."""
    cells = [[c.strip() for c in line.strip().strip("|").split("|")]
             for line in (FOLDER / "README.md").read_text().splitlines() if line.startswith("| ")]
    return [row for row in cells if len(row) == columns and row[0] in HEADS]


def figure(cell: str) -> tuple[float, float]:
    match = FIGURE.search(cell)
    assert match, f"no 'mean ± error' in {cell!r}"
    return float(match.group(1)), float(match.group(2))


def rounded(mean: float, error: float) -> tuple[float, float]:
    return round(mean, 2), round(error, 2)


def test_the_main_table_is_the_json_files():
    found = rows(7)
    assert len(found) == 4
    for head, split, floor, shipped, tuned, paired, oracle in found:
        name = HEADS[head]
        kemar, fine = results(name, "kemar_trained")[split], results(name, "head_trained")[split]
        score = lambda r, estimate: rounded(r["summary"][estimate]["si_sdr"], r["summary"][estimate]["si_sdr_sem"])  # noqa: E731
        assert figure(floor) == score(kemar, "mixture")
        assert figure(shipped) == score(kemar, "separator")
        assert figure(tuned) == score(fine, "separator")
        assert figure(oracle) == score(kemar, "oracle")
        difference = fine["paired"]["separator"]["si_sdr"]
        assert figure(paired) == rounded(difference["mean"], difference["sem"])


@pytest.mark.parametrize("split, column", [("heard", 1), ("unheard", 2)])
def test_the_longer_fine_tune_table_is_the_json_files(split, column):
    found = rows(4)
    assert len(found) == 2
    for row in found:
        difference = results(HEADS[row[0]], "head_trained_long")[split]["paired"]["separator"]["si_sdr"]
        assert figure(row[column]) == rounded(difference["mean"], difference["sem"])
