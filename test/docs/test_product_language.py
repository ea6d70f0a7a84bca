"""The product speaks of the software, not of how it was made: no work-period numbers, folder suffixes or
internal issue numbers in any tracked file (code, docs, params, tests, result folders, the shipped
checkpoints' stored metadata), and every docs/ path that code or docs name exists."""

import re
import subprocess
from pathlib import Path

import pytest

from m2h_ros.paths import REPO_DIR

HISTORY = re.compile(
    r"\bsessions? \d"              # a work period by number
    r"|_s\d\d\b|_session\d"        # a folder or run named by its work period
    r"|\bthe VM of\b"              # a machine as a chapter of a history
    r"|\bissues? #?\d+\b",         # an internal issue number (another project's issue names its repository)
    re.IGNORECASE)
OTHER_PROJECT = re.compile(r"[\w.-]+/[\w.-]+(#\d+|/issues/\d+)|github\.com", re.IGNORECASE)
# Compressed or media files whose bytes cannot hold readable text.
SKIP_SUFFIXES = {".png", ".jpg", ".jpeg", ".gif", ".mp4", ".wav", ".flac", ".npy", ".npz", ".mcap", ".gz", ".zip"}
DOCS_PATH = re.compile(r"""(?<![\w/.-])docs/[^\s`'"()\[\]|,;]+""")
IN_COMMIT = re.compile(r"\bcommit `?[0-9a-f]{7,40}\b")
BUILT = ("docs/_build",)  # written by the docs build, ignored by git
# How the software came to be, which belongs in CHANGELOG.md: a commit named as where something is, a
# comparison with an earlier state told as a story, a remark about the machine the text was written on.
MAKING_OF = re.compile(
    r"(?<![\w@/.-])(?=[0-9a-f]{7}\b)(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7}(?![\w-])"  # a short commit hash
    r"|\bcommit `?[0-9a-f]{7,40}\b"
    r"|\bused to be\b|\bit used to\b|\bnow runs\b|\bold output\b|\banother day\b|\bworth measuring again\b"
    r"|\bafter a refactor\b|\bthese machines\b|\bhas no display\b|\(no display\)|\btarget is missed\b"
    r"|tables without this sentence")
# The changelog is the history; a vendored package names the upstream commit it was copied from.
HISTORY_PLACES = ("CHANGELOG.md", "third_party/")
THIS_FILE = Path(__file__).resolve().relative_to(REPO_DIR).as_posix()


def _tracked() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO_DIR, check=True, capture_output=True).stdout
    return [p for p in out.decode().split("\0") if p and p != THIS_FILE and (REPO_DIR / p).is_file()]


@pytest.fixture(scope="module")
def files():
    return _tracked()


def history_hits(text: str) -> list[str]:
    hits = []
    for number, line in enumerate(text.splitlines(), 1):
        for match in HISTORY.finditer(line):
            if match.group(0).lower().startswith("issue") and OTHER_PROJECT.search(line):
                continue
            hits.append(f"{number}: {line.strip()[:160]}")
    return hits


def test_the_patterns_find_history_and_pass_the_product():
    # Built from parts, so this file does not hold what it looks for (the repository's own grep stays empty).
    for diary in ("as measured in session " + "12", "runs/nav_fromq_s" + "31/policy.pt", "switch_time_val_session10",
                  "fixed for issue 9", "on the VM of that day"):
        assert history_hits(diary), diary
    for product in ("a session of the ROS graph", "_s10x", "pcm-s16", "rosbag2 issue ros2/rosbag2#1234",
                    "SI-SDR 3.82 dB over 500 episodes"):
        assert not history_hits(product), product


def test_no_tracked_file_speaks_of_how_it_was_made(files):
    found = {}
    for path in files:
        if Path(path).suffix.lower() in SKIP_SUFFIXES:
            continue
        # Checkpoints (.pt: zip, stored uncompressed) are read as bytes: their metadata is text inside.
        text = (REPO_DIR / path).read_bytes().decode("latin-1")
        hits = history_hits(text)
        if hits:
            found[path] = hits[:3]
    assert not found, "work-period references:\n" + "\n".join(f"{p}: {h}" for p, hs in found.items() for h in hs)


def making_of_hits(text: str) -> list[str]:
    return [f"{number}: {line.strip()[:160]}" for number, line in enumerate(text.splitlines(), 1)
            if MAKING_OF.search(line)]


def test_the_making_of_patterns_find_history_and_pass_the_product():
    # Built from parts, so this file does not hold what it looks for.
    for diary in ("the result folder is in commit `6f0a" + "a1c`", "git show a9c9" + "376:m2h_ros/x.pt", "it used" + " to be",
                  "as the project " + "now runs CUDA", "another " + "day 441 / 411", "(this machine has no " + "display)"):
        assert making_of_hits(diary), diary
    for product in ("sha256 28febfab8bc2", "home@1945bc8e06a4aa83", "acoustics v2 10638cd03a526cd3", "the separator is used to "
                    "compute", "a deadbee", "1234567 steps"):
        assert not making_of_hits(product), product


def test_no_tracked_text_tells_how_it_was_made(files):
    found = {}
    for path in files:
        if path.startswith(HISTORY_PLACES) or Path(path).suffix.lower() in SKIP_SUFFIXES | {".pt", ".csv", ".json"}:
            continue
        try:
            hits = making_of_hits((REPO_DIR / path).read_text())
        except UnicodeDecodeError:
            continue
        if hits:
            found[path] = hits[:3]
    assert not found, ("history in the product (say it in the present tense, with its evidence; history goes in "
                       "CHANGELOG.md):\n" + "\n".join(f"{p}: {h}" for p, hs in found.items() for h in hs))


def _named_docs_paths(text: str) -> set[str]:
    names = set()
    for line in text.splitlines():
        if IN_COMMIT.search(line):
            continue  # a path as a named commit holds it (git show COMMIT:PATH), not in today's tree
        for match in DOCS_PATH.finditer(line):
            name = match.group(0).split("#", 1)[0].rstrip(".:/")
            if not any(c in name for c in "<>*{}$") and not name.startswith(BUILT):
                names.add(name)
    return names


def test_every_docs_path_named_exists(files):
    missing = {}
    for path in files:
        if Path(path).suffix.lower() in SKIP_SUFFIXES | {".pt", ".csv"}:
            continue
        try:
            text = (REPO_DIR / path).read_text()
        except UnicodeDecodeError:
            continue
        gone = sorted(n for n in _named_docs_paths(text) if not (REPO_DIR / n).exists())
        if gone:
            missing[path] = gone
    assert not missing, "docs paths that do not exist:\n" + "\n".join(f"{p}: {g}" for p, g in missing.items())
