"""Sphinx extension of the m2h_ros docs.

The pages are plain Markdown that GitHub renders as well: the reference tables are written into them
by ``scripts/make_reference.py`` (test/docs/test_reference_pages.py checks they are fresh), and
cross-references are relative links. This extension only does what the site needs beyond that:

* a link to a repository path outside docs/ (``[`scripts/evaluate.py`](../../scripts/evaluate.py)``,
  a folder such as ``params/``) shows as that path in code style, since the site does not hold the
  repository; one that does not exist is a build warning (an error under ``-W``);
* ``results/``: the results index gets a hidden toctree of every folder's README (so they nest under
  it in the navigation); the tables the scripts wrote are pages linked from those READMEs, marked as
  orphans, and one that opens without a heading (``paired.md``) gets its path as its title.
"""

from __future__ import annotations

from pathlib import Path

from docutils import nodes
from sphinx import addnodes
from sphinx.transforms import SphinxTransform

ROOT = Path(__file__).resolve().parents[2]


class RepositoryLinks(SphinxTransform):
    """Relative links that leave docs/ become the path they name, checked to exist. MyST makes a link to a
    file outside the site a download link, to a folder an unresolvable reference, and to a Markdown file
    outside the site (``CHANGELOG.md``) a reference to an unknown page."""

    default_priority = 500

    def apply(self, **kwargs) -> None:
        here = Path(self.env.doc2path(self.env.docname)).parent
        docs = Path(self.env.srcdir).resolve()
        for node in list(self.document.findall(addnodes.download_reference)) + list(
                self.document.findall(addnodes.pending_xref)):
            if node.get("reftype") != "myst" and not isinstance(node, addnodes.download_reference):
                continue
            if node.get("refdomain") == "doc":
                if node["reftarget"] in self.env.found_docs:
                    continue
                path = (docs / node["reftarget"]).with_suffix(".md").resolve()  # MyST's docname, suffix dropped
            elif node.get("refdomain") is None:
                path = (here / node["reftarget"].split("#", 1)[0]).resolve()
                if path.is_relative_to(docs) and not path.is_dir():
                    continue  # a file of the site's own (a results table, a JSON file): Sphinx serves it
            else:
                continue
            if not path.exists():
                self.document.reporter.warning(f"linked path does not exist: {path}", base_node=node)
            text = node.astext()
            node.replace_self(nodes.literal(text, text))


RESULTS_INDEX_TOCTREE = "\n\n```{toctree}\n:hidden:\n:glob:\n\n*/README\n*/*/README\n```\n"


def results_pages(app, docname: str, source: list[str]) -> None:
    """docs/results/ as pages: the index's READMEs nest under it; the generated tables are orphans."""
    if docname == "results/README":
        source[0] += RESULTS_INDEX_TOCTREE
    elif docname.startswith("results/") and not docname.endswith("/README"):
        heading = "" if source[0].lstrip().startswith("#") else f"# {docname.removeprefix('results/')}\n\n"
        source[0] = "---\norphan: true\n---\n" + heading + source[0]


def setup(app):
    app.connect("source-read", results_pages)
    app.add_transform(RepositoryLinks)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
