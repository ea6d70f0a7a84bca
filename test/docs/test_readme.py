"""The README orients in a screen or two: short, tables with short cells, and the two commands."""

import re

from m2h_ros.paths import REPO_DIR

README = REPO_DIR / "README.md"
MAX_CHARS = 12_000
MAX_CELL = 300


def test_the_readme_is_short():
    assert len(README.read_text()) < MAX_CHARS


def test_no_table_cell_is_a_paragraph():
    for line in README.read_text().splitlines():
        if line.startswith("|"):
            for cell in re.split(r"(?<!\\)\|", line.strip())[1:-1]:
                assert len(cell.strip()) <= MAX_CELL, cell


def test_it_names_the_two_commands():
    text = README.read_text()
    assert "`scripts/test.sh`" in text and "`scripts/main_job.sh`" in text
