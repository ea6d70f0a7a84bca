"""Sphinx extension of the m2h_ros docs: reference tables generated from the code, so they cannot
drift from it, and a role that checks repository paths.

* ``{m2h-config} m2h_ros.node_configs.SimConfig``: a node's parameters (name, type, default,
  description, range or choices) from its frozen config dataclass.
* ``{m2h-topics}``: the pipeline's topics and their message types from ``m2h_ros/topics.py``.
* ``{m2h-qos}``: every QoS profile of ``m2h_ros/ros/qos.py`` and the comment that explains it (read
  from the source, so the docs build needs no ROS).
* ``{m2h-messages}``: every ``msg_defs/msg/*.msg``, whole.
* ``{m2h-commands} scripts/*.py``: each matching script with the first paragraph of its docstring.
* ``{m2h-help} m2h_ros.replay_cli:build_parser m2h-eval``: a command's ``--help``, from its parser.
* ``{repo}`path``: a repository path in code style; a path that does not exist is a build warning
  (an error under ``-W``).
* ``results/``: the results index gets a hidden toctree of every folder's README (so they nest under
  it in the navigation); the tables the scripts wrote are pages linked from those READMEs, marked as
  orphans, and one that opens without a heading (``paired.md``) gets its path as its title.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import typing
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import Directive
from sphinx.util import logging

ROOT = Path(__file__).resolve().parents[2]
LOG = logging.getLogger(__name__)


def _table(header: list[str], rows: list[list[nodes.Node]], widths: list[int]) -> nodes.table:
    table = nodes.table(classes=["m2h-generated"])
    group = nodes.tgroup(cols=len(header))
    table += group
    group.extend(nodes.colspec(colwidth=w) for w in widths)
    head = nodes.thead()
    head += nodes.row("", *(nodes.entry("", nodes.paragraph(text=h)) for h in header))
    group += head
    body = nodes.tbody()
    for cells in rows:
        body += nodes.row("", *(nodes.entry("", nodes.paragraph("", "", cell)) for cell in cells))
    group += body
    return table


def _type_name(kind) -> str:
    if typing.get_origin(kind) is tuple:
        return f"list of {typing.get_args(kind)[0].__name__}"
    return kind.__name__


def _bounds(meta) -> str:
    if meta.get("choices") is not None:
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    low, high = meta.get("min"), meta.get("max")
    if low is None and high is None:
        return ""
    return f"[{'-inf' if low is None else low}, {'inf' if high is None else high}]"


class ConfigTable(Directive):
    """The parameters of one node config dataclass, as the node declares them."""

    required_arguments = 1

    def run(self):
        module, _, name = self.arguments[0].rpartition(".")
        cls = getattr(importlib.import_module(module), name)
        hints = typing.get_type_hints(cls)
        rows = []
        for field in dataclasses.fields(cls):
            default = field.default
            shown = repr(list(default) if isinstance(default, tuple) else default)
            rows.append([nodes.literal(text=field.name), nodes.Text(_type_name(hints[field.name])),
                         nodes.literal(text=shown), nodes.Text(field.metadata.get("description", "")),
                         nodes.Text(_bounds(field.metadata))])
        return [_table(["parameter", "type", "default", "description", "allowed"], rows, [14, 8, 12, 50, 16])]


class TopicTable(Directive):
    """Topic name constants of m2h_ros/topics.py with their trailing comments."""

    def run(self):
        source = (ROOT / "m2h_ros" / "topics.py").read_text().splitlines()
        rows = []
        for node in ast.parse("\n".join(source)).body:
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
                line = source[node.lineno - 1]
                comment = line.split("#", 1)[1].strip() if "#" in line else ""
                rows.append([nodes.literal(text=node.value.value), nodes.literal(text=node.targets[0].id),
                             nodes.Text(comment)])
        return [_table(["topic", "constant", "type and publisher"], rows, [25, 18, 57])]


def _policy(node: ast.expr, constants: dict[str, object]) -> str:
    """``ReliabilityPolicy.RELIABLE`` -> "reliable"; a name -> its constant's value."""
    if isinstance(node, ast.Attribute):
        return node.attr.lower().replace("_", " ")
    if isinstance(node, ast.Name):
        return str(constants[node.id])
    return str(ast.literal_eval(node))


class QosTable(Directive):
    """The QoSProfile assignments of m2h_ros/ros/qos.py with the comment block above each."""

    def run(self):
        lines = (ROOT / "m2h_ros" / "ros" / "qos.py").read_text().splitlines()
        constants: dict[str, object] = {}
        rows = []
        for node in ast.parse("\n".join(lines)).body:
            if not isinstance(node, ast.Assign) or not isinstance(node.targets[0], ast.Name):
                continue
            name = node.targets[0].id
            if isinstance(node.value, ast.Constant):
                constants[name] = node.value.value
            elif isinstance(node.value, ast.Call) and getattr(node.value.func, "id", "") == "QoSProfile":
                policy = {k.arg: _policy(k.value, constants) for k in node.value.keywords}
                comment, at = [], node.lineno - 2
                while at >= 0 and lines[at].split("=")[0].strip().isupper():  # its own constants, e.g. a depth
                    at -= 1
                while at >= 0 and lines[at].lstrip().startswith("#"):
                    comment.insert(0, lines[at].lstrip("# ").strip())
                    at -= 1
                rows.append([nodes.literal(text=name), nodes.Text(f"{policy['history']} {policy['depth']}"),
                             nodes.Text(policy["reliability"]), nodes.Text(policy["durability"]),
                             nodes.Text(" ".join(comment))])
        if not rows:
            LOG.warning("no QoSProfile found in m2h_ros/ros/qos.py", location=self.state.document)
        return [_table(["profile", "history", "reliability", "durability", "why"], rows, [12, 12, 10, 12, 54])]


class MessageDefinitions(Directive):
    """Every message definition of the m2h_msgs package, as a section with the file's text."""

    def run(self):
        out = []
        for path in sorted((ROOT / "msg_defs" / "msg").glob("*.msg")):
            section = nodes.section(ids=[nodes.make_id(f"msg-{path.stem}")])
            section += nodes.title(text=f"m2h_msgs/{path.stem}")
            text = path.read_text()
            block = nodes.literal_block(text, text)
            block["language"] = "text"
            section += block
            out.append(section)
        return out


class CommandList(Directive):
    """Each script matching the glob, with the first paragraph of its module docstring."""

    required_arguments = 1

    def run(self):
        rows = []
        for path in sorted(ROOT.glob(self.arguments[0])):
            doc = ast.get_docstring(ast.parse(path.read_text())) or ""
            if not doc:
                LOG.warning(f"{path.relative_to(ROOT)} has no docstring to list", location=self.state.document)
            summary = " ".join(doc.split("\n\n")[0].split())
            rows.append([nodes.literal(text=str(path.relative_to(ROOT))), nodes.Text(summary)])
        if not rows:
            LOG.warning(f"no file matches {self.arguments[0]}", location=self.state.document)
        return [_table(["command", "what it does"], rows, [30, 70])]


class CommandHelp(Directive):
    """The ``--help`` text of a command whose argparse parser a function builds."""

    required_arguments = 2

    def run(self):
        module, _, function = self.arguments[0].partition(":")
        parser = getattr(importlib.import_module(module), function)()
        parser.prog = self.arguments[1]
        text = parser.format_help()
        block = nodes.literal_block(text, text)
        block["language"] = "text"
        return [block]


def repo_role(name, rawtext, text, lineno, inliner, options=None, content=None):
    """``{repo}`path```: a repository path, checked to exist."""
    path = text.strip()
    if not (ROOT / path.split("#")[0]).exists():
        return [nodes.literal(rawtext, path)], [inliner.reporter.warning(f"repository path does not exist: {path}",
                                                                         line=lineno)]
    return [nodes.literal(rawtext, path)], []


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
    app.add_directive("m2h-config", ConfigTable)
    app.add_directive("m2h-topics", TopicTable)
    app.add_directive("m2h-qos", QosTable)
    app.add_directive("m2h-messages", MessageDefinitions)
    app.add_directive("m2h-commands", CommandList)
    app.add_directive("m2h-help", CommandHelp)
    app.add_role("repo", repo_role)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
