"""Sphinx configuration of the m2h_ros documentation (Sphinx + MyST + furo).

Build: ``python -m sphinx -W --keep-going -b html docs docs/_build/html`` (the suite runs the same,
test/docs/test_docs_site.py)."""

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path[:0] = [str(DOCS / "_ext"), str(ROOT)]

project = "m2h_ros"
author = "m2h_ros developers"
copyright = "m2h_ros developers, Apache-2.0"
release = re.search(r"<version>([^<]+)</version>", (ROOT / "package.xml").read_text()).group(1)
version = release

extensions = ["myst_parser", "m2h_docs"]
source_suffix = {".md": "markdown"}
root_doc = "index"
# docs/results/ is part of the site: each folder's README and the tables the scripts wrote.
exclude_patterns = ["_build", "_ext", "videos/**"]
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3
# Links to repository files (scripts, params, result folders) are checked by m2h_docs, which
# resolves them against the repository; Sphinx itself checks every link between pages.
nitpicky = False
suppress_warnings = []

html_theme = "furo"
html_title = f"m2h_ros {release}"
html_static_path = []
