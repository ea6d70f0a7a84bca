"""One version everywhere: package.xml, m2h_msgs' package.xml, setup.py, m2h_ros.__version__,
CITATION.cff and the newest CHANGELOG.md entry."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def versions() -> dict[str, str]:
    def find(path: str, pattern: str) -> str:
        match = re.search(pattern, (ROOT / path).read_text(), re.MULTILINE)
        assert match, f"no version in {path} (pattern {pattern!r})"
        return match.group(1)

    return {"package.xml": find("package.xml", r"<version>([^<]+)</version>"),
            "msg_defs/package.xml": find("msg_defs/package.xml", r"<version>([^<]+)</version>"),
            "setup.py": find("setup.py", r"^\s*version=\"([^\"]+)\""),
            "m2h_ros/__init__.py": find("m2h_ros/__init__.py", r"^__version__ = \"([^\"]+)\"$"),
            "CITATION.cff": find("CITATION.cff", r"^version:\s*\"?([^\"\s]+)\"?\s*$"),
            "CHANGELOG.md": find("CHANGELOG.md", r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$")}


def test_every_file_names_the_same_version():
    found = versions()
    assert len(set(found.values())) == 1, found


def test_the_citation_dates_the_release_of_the_newest_changelog_entry():
    changelog = re.search(r"^## \[[^\]]+\] - (\d{4}-\d{2}-\d{2})$", (ROOT / "CHANGELOG.md").read_text(), re.MULTILINE)
    citation = re.search(r"^date-released:\s*\"?(\d{4}-\d{2}-\d{2})\"?", (ROOT / "CITATION.cff").read_text(), re.MULTILINE)
    assert changelog and citation and changelog.group(1) == citation.group(1)
