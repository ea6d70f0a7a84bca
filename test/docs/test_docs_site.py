"""The documentation site builds with Sphinx, warnings as errors: a broken link between pages, a
missing anchor, a repository path that does not exist, or a page outside the navigation fails it."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from m2h_ros import node_configs

ROOT = Path(__file__).resolve().parents[2]


def build(out: Path, source: Path = ROOT / "docs") -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-d", str(out / "doctrees"), str(source), str(out / "html")],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("docs")
    result = build(out)
    assert result.returncode == 0, result.stdout + result.stderr
    return out / "html"


def test_the_docs_site_builds_without_warnings(site):
    assert (site / "index.html").is_file() and (site / "reference" / "nodes.html").is_file()
    # Every markdown file under docs/ is a page: Sphinx warns (fails) on one outside the navigation.
    pages = {p.relative_to(ROOT / "docs").with_suffix(".html") for p in (ROOT / "docs").rglob("*.md")
             if "_build" not in p.parts}
    assert not {page for page in pages if not (site / page).is_file()}


def test_the_node_reference_is_generated_from_the_config_dataclasses(site):
    page = (site / "reference" / "nodes.html").read_text()
    configs = [cls for cls in vars(node_configs).values()
               if dataclasses.is_dataclass(cls) and cls.__module__ == node_configs.__name__]
    assert len(configs) >= 5
    for cls in configs:  # every node's config, a new node's included
        for field in dataclasses.fields(cls):
            assert f"<code class=\"docutils literal notranslate\"><span class=\"pre\">{field.name}</span></code>" \
                in page, f"{cls.__name__}.{field.name} missing from the node reference"
