"""The README's headline table is what scripts/headline_table.py computes from the committed results:
a number in the README cannot drift from its result file."""

import csv
import shutil

import pytest

from m2h_ros.paths import REPO_DIR
from scripts_as_modules import load_script

README = REPO_DIR / "README.md"
RESULTS = REPO_DIR / "docs" / "results"


@pytest.fixture(scope="module")
def headline():
    return load_script("headline_table")


def _copy_results(tmp_path):
    # Only the tables the script reads (the figures and logs are not needed).
    copy = tmp_path / "results"
    for table in RESULTS.rglob("results.csv"):
        target = copy / table.relative_to(RESULTS)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(table, target)
    return copy


def test_the_readme_table_is_the_generated_one(headline):
    assert headline.main(["--check", str(README)]) == 0


def test_every_row_links_an_existing_result_folder(headline):
    table = headline.build_table(RESULTS)
    rows = table.splitlines()[2:]
    assert len(rows) >= 12
    for row in rows:
        folder = row.rsplit("](", 1)[1].split(")", 1)[0]
        assert (REPO_DIR / folder / "README.md").is_file(), row


def test_a_changed_result_file_fails_the_check(headline, tmp_path, capsys):
    copy = _copy_results(tmp_path)
    assert headline.main(["--check", str(README), "--results", str(copy)]) == 0
    table = copy / "far_target" / "results.csv"
    with table.open(newline="") as stream:
        rows = list(csv.DictReader(stream))
    first = next(r for r in rows if r["controller"] == "move2hear_navigation" and r["sound_split"] == "heard")
    first["final_si_sdr"] = f"{float(first['final_si_sdr']) + 100:.6f}"  # +0.2 dB on the heard mean of 500
    with table.open("w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    assert headline.main(["--check", str(README), "--results", str(copy)]) == 1
    assert "differs" in capsys.readouterr().err


def test_write_replaces_only_the_table(headline, tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n\n{headline.START}\nold\n{headline.END}\n\nrest\n")
    assert headline.main(["--write", str(readme)]) == 0
    text = readme.read_text()
    assert text.startswith("intro\n\n") and text.endswith("\n\nrest\n") and "| Near-target" in text
    assert headline.main(["--check", str(readme)]) == 0
