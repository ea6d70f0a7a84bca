#!/usr/bin/env python3
"""Writes the generated parts of the documentation as plain Markdown, so the pages read the same on
GitHub and on the Sphinx site: the reference tables (node parameters, topics, QoS profiles, launch
arguments, world-file settings, messages, commands and their --help, the Python API), and every
cross-reference as a relative Markdown link.

    python scripts/make_reference.py          # rewrite the pages under docs/ whose generated parts changed
    python scripts/make_reference.py --check  # exit 1, naming the stale pages, when a page differs

A generated part sits between ``<!-- reference: KIND ARGUMENTS -->`` and ``<!-- reference: end -->``;
only that part is rewritten. KIND is one of: ``config MODULE.CLASS`` (a node's parameters from its
config dataclass), ``topics``, ``qos``, ``launch launch/FILE`` (a launch file's arguments),
``world-file`` (an imported world's settings), ``messages``, ``executables`` (the installed console
scripts and launch files), ``commands GLOB`` (scripts with their docstrings' first paragraph),
``help MODULE:FUNCTION PROG`` (a command's --help) and ``python MODULE:NAME`` (a class's or function's
signature and docstrings) and ``contents`` (links to the pages of the page's own toctree, for GitHub,
which shows a toctree as a code block). A MyST role written by hand, ``{doc}`page``` or ``{repo}`path```, becomes a
relative link: ``[Page title](page.md)``, ``[`path`](../../path)``.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import inspect
import os
import re
import sys
import typing
from pathlib import Path

import yaml

from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.paths import REPO_DIR

DOCS = REPO_DIR / "docs"
BLOCK = re.compile(r"(<!-- reference: (?P<spec>(?!end\b)[^>]*?) -->\n)(?P<body>.*?)(<!-- reference: end -->)", re.S)
ROLE = re.compile(r"\{(?P<role>doc|repo)\}`(?P<target>[^`]+)`")


def cell(text: str) -> str:
    """Text for one Markdown table cell: one line, its pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def code(text: str) -> str:
    text = str(text)
    fence = "``" if "`" in text else "`"
    return f"{fence}{' ' if fence == '``' else ''}{text}{' ' if fence == '``' else ''}{fence}"


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def fenced(text: str, language: str = "text") -> str:
    return f"```{language}\n{text.rstrip()}\n```\n"


def _type_name(kind) -> str:
    if typing.get_origin(kind) is tuple:
        return f"list of {typing.get_args(kind)[0].__name__}"
    return kind.__name__


def _allowed(meta) -> str:
    if meta.get("choices") is not None:
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    low, high = meta.get("min"), meta.get("max")
    if low is None and high is None:
        return ""
    return f"[{'-inf' if low is None else low}, {'inf' if high is None else high}]"


def _shown(value) -> str:
    return repr(list(value) if isinstance(value, tuple) else value)


def config_table(name: str) -> str:
    """The parameters of one node config dataclass, as the node declares them."""
    module, _, attribute = name.rpartition(".")
    cls = getattr(importlib.import_module(module), attribute)
    hints = typing.get_type_hints(cls)
    rows = [[code(f.name), cell(_type_name(hints[f.name])), code(_shown(f.default)),
             cell(f.metadata.get("description", "")), cell(_allowed(f.metadata))] for f in dataclasses.fields(cls)]
    return table(["parameter", "type", "default", "description", "allowed"], rows)


def _trailing_comment(line: str) -> str:
    return line.split("#", 1)[1].strip() if "#" in line else ""


def topic_table() -> str:
    """Topic name constants of m2h_ros/topics.py with their trailing comments."""
    source = (REPO_DIR / "m2h_ros" / "topics.py").read_text().splitlines()
    rows = [[code(node.value.value), code(node.targets[0].id), cell(_trailing_comment(source[node.lineno - 1]))]
            for node in ast.parse("\n".join(source)).body
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant)]
    return table(["topic", "constant", "type and publisher"], rows)


def _policy(node: ast.expr, constants: dict[str, object]) -> str:
    """``ReliabilityPolicy.RELIABLE`` -> "reliable"; a name -> its constant's value."""
    if isinstance(node, ast.Attribute):
        return node.attr.lower().replace("_", " ")
    if isinstance(node, ast.Name):
        return str(constants[node.id])
    return str(ast.literal_eval(node))


def qos_table() -> str:
    """The QoSProfile assignments of m2h_ros/ros/qos.py with the comment block above each (read from
    the source, so the docs need no ROS)."""
    lines = (REPO_DIR / "m2h_ros" / "ros" / "qos.py").read_text().splitlines()
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
            rows.append([code(name), f"{policy['history']} {policy['depth']}", policy["reliability"],
                         policy["durability"], cell(" ".join(comment))])
    if not rows:
        raise ConfigError("no QoSProfile found in m2h_ros/ros/qos.py")
    return table(["profile", "history", "reliability", "durability", "why"], rows)


def _params_file_value(node: str, field: str, config_cls: type):
    document = yaml.safe_load((REPO_DIR / "params" / f"{node}.yaml").read_text()) or {}
    values = document.get(node, {}).get("ros__parameters", {})
    return values[field] if field in values else next(f.default for f in dataclasses.fields(config_cls)
                                                        if f.name == field)


def _launch_value(value) -> str:
    """A value as typed after ``:=``."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return value or '""'
    return _shown(value).replace("'", "")


def _launch_namespace(tree: ast.Module) -> dict:
    """The names a launch file takes from m2h_ros's ROS-free modules and the module-level values it builds
    from them, so its arguments read without ROS's launch packages (a name from m2h_ros.ros is left out: an
    expression using it is computed when the launch starts)."""
    namespace: dict = {}
    for node in tree.body:
        module_name = node.module or "" if isinstance(node, ast.ImportFrom) else ""
        # The core only: m2h_ros.ros needs ROS's launch packages (the import boundary keeps them there).
        if module_name.startswith("m2h_ros") and not module_name.startswith(("m2h_ros.ros", "m2h_ros.nodes")):
            module = importlib.import_module(module_name)
            namespace.update({alias.asname or alias.name: getattr(module, alias.name) for alias in node.names})
        elif isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            try:
                namespace[node.targets[0].id] = _evaluated(node.value, namespace)
            except NameError:
                continue
    return namespace


def _evaluated(expression: ast.expr, namespace: dict):
    return eval(compile(ast.Expression(expression), "<launch file>", "eval"), dict(namespace))  # noqa: S307


def _recorded(*args, **kwargs) -> tuple[tuple, dict]:
    """Stands in for DeclareLaunchArgument: what it was called with."""
    return args, kwargs


def _declared(tree: ast.Module, namespace: dict) -> list[tuple[tuple, dict]]:
    """The (args, kwargs) of each DeclareLaunchArgument the file makes, those a comprehension makes included
    (the comprehension is evaluated with the call recorded, so its loop variables are bound)."""
    namespace = {**namespace, "DeclareLaunchArgument": _recorded}
    is_declaration = lambda node: (isinstance(node, ast.Call)  # noqa: E731
                                   and getattr(node.func, "id", "") == "DeclareLaunchArgument")
    declared, inside = [], set()
    for node in ast.walk(tree):  # breadth first: a comprehension before the call inside it
        if isinstance(node, ast.ListComp | ast.GeneratorExp) and is_declaration(node.elt):
            inside.add(id(node.elt))
            declared += list(_evaluated(node, namespace))
        elif is_declaration(node) and id(node) not in inside:
            declared.append(_evaluated(node, namespace))
    return declared


def launch_table(path: str) -> str:
    """A launch file's arguments: each ``Argument(name, node, field)`` with the node parameter it sets, its
    default (the node's params file unless the launch file gives one) and the field's description; then
    each argument the file declares directly. A default computed when the launch starts (a fresh run
    directory) is not a fixed value: its description says what it is."""
    from m2h_ros.node_configs import NODE_CONFIGS, ROBOT_CONFIGS

    configs = {**NODE_CONFIGS, **ROBOT_CONFIGS}
    tree = ast.parse((REPO_DIR / path).read_text())
    namespace = _launch_namespace(tree)
    rows = []
    for call in ast.walk(tree):
        if not isinstance(call, ast.Call) or getattr(call.func, "id", "") != "Argument":
            continue
        name, node, field = (_evaluated(a, namespace) for a in call.args)
        keywords = {}
        for keyword in call.keywords:
            try:
                keywords[keyword.arg] = _evaluated(keyword.value, namespace)
            except NameError:  # computed by a function of ROS's launch packages when the launch starts
                keywords[keyword.arg] = None
        cls = configs[node]
        meta = next(f.metadata for f in dataclasses.fields(cls) if f.name == field)
        if "default" in keywords and keywords["default"] is None:
            default = "see description"
        elif "default" in keywords:
            default = code(keywords["default"])
        else:
            default = code(_launch_value(_params_file_value(node, field, cls)))
        description = keywords.get("description") or meta.get("description", "")
        rows.append([code(f"{name}:="), code(f"{node}.{field}"), default, cell(description), cell(_allowed(meta))])
    for args, kwargs in _declared(tree, namespace):
        choices = kwargs.get("choices")
        rows.append([code(f"{args[0]}:="), "", code(kwargs["default_value"]), cell(kwargs["description"]),
                     cell("one of " + ", ".join(map(repr, choices)) if choices else "")])
    if not rows:
        raise ConfigError(f"{path} declares no launch argument")
    return table(["argument", "sets", "default", "description", "allowed"], rows)


def _field_comments(cls: type) -> dict[str, str]:
    """``name: type = default  # comment`` -> {name: comment} from a dataclass's source."""
    comments = {}
    for line in inspect.getsource(cls).splitlines():
        match = re.match(r"\s+(\w+): [^=]+=.*?#\s*(.*)$", line)
        if match:
            comments[match.group(1)] = match.group(2)
    return comments


def world_file_table() -> str:
    """The settings of an imported world's ``<stem>.world.yaml`` (WorldFile, its plan's PlanSettings)."""
    from m2h_ros.core.world.plan_world import PlanSettings
    from m2h_ros.core.world.worlds import WorldFile

    rows = []
    for cls, applies in ((PlanSettings, "map, mesh"), (WorldFile, "mesh")):
        comments = _field_comments(cls)
        for field in dataclasses.fields(cls):
            if field.name in ("plan", "path"):  # the nesting itself and the file's own path, not keys
                continue
            comment = comments.get(field.name, "")
            rows.append([code(field.name), code(_shown(field.default)), applies,
                         cell(comment.removeprefix("mesh: "))])
    return table(["key", "default", "worlds", "meaning"], rows)


def message_sections() -> str:
    """Every message definition of the m2h_msgs package, whole."""
    parts = []
    for path in sorted((REPO_DIR / "msg_defs" / "msg").glob("*.msg")):
        parts.append(f"## m2h_msgs/{path.stem}\n\n{fenced(path.read_text())}")
    return "\n".join(parts)


def _docstring_summary(path: Path) -> str:
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    if not doc:
        raise ConfigError(f"{path.relative_to(REPO_DIR)} has no docstring to list")
    return " ".join(doc.split("\n\n")[0].split())


def command_table(pattern: str) -> str:
    """Each script matching the glob, with the first paragraph of its module docstring."""
    paths = sorted(REPO_DIR.glob(pattern))
    if not paths:
        raise ConfigError(f"no file matches {pattern}")
    return table(["command", "what it does"],
                 [[code(path.relative_to(REPO_DIR).as_posix()), cell(_docstring_summary(path))] for path in paths])


def _module_constant(path: Path, name: str):
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == name:
            return ast.literal_eval(node.value)
    raise ConfigError(f"{path} defines no {name}")


def _first_sentence(text: str) -> str:
    text = " ".join(text.split())
    return text.split(". ", 1)[0].rstrip(".") + "."


def executable_table() -> str:
    """What the package installs: each node, the console scripts of setup.py and the launch files."""
    nodes = _module_constant(REPO_DIR / "m2h_ros" / "nodes" / "entry.py", "NODES")
    rows = [[code(f"ros2 run m2h_ros {node}"), f"the node [{node}](nodes.md#{node})"]
            for node in nodes]
    setup = (REPO_DIR / "setup.py").read_text()
    for name, target in re.findall(r'"(m2h-[\w-]+)": "([\w.]+):main"', setup):
        summary = _first_sentence((importlib.import_module(target).__doc__ or "").split("\n\n")[0])
        rows.append([code(name), cell(summary.removeprefix(f"``{name}``: "))])
    for path in sorted((REPO_DIR / "launch").glob("*.launch.py")):
        # The docstring opens with the command line; its second paragraph says what the file starts.
        paragraphs = (ast.get_docstring(ast.parse(path.read_text())) or "").split("\n\n")
        rows.append([code(f"ros2 launch m2h_ros {path.name}"),
                     cell(_first_sentence(paragraphs[1]) + f" ([arguments](#{path.name.replace('.', '')}))")])
    return table(["command", "what it does"], rows)


def help_block(target: str, prog: str) -> str:
    """The ``--help`` text of a command whose argparse parser a function builds."""
    module, _, function = target.partition(":")
    parser = getattr(importlib.import_module(module), function)()
    parser.prog = prog
    # argparse wraps to the terminal's width: fixed here so the page does not depend on who wrote it.
    os.environ["COLUMNS"] = "100"
    return fenced(parser.format_help())


def _short(value) -> str:
    """A default as the reader would write it: a config dataclass by the fields it changes."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        changed = [f"{f.name}={_short(getattr(value, f.name))}" for f in dataclasses.fields(value)
                   if f.init and f.default is not dataclasses.MISSING and getattr(value, f.name) != f.default]
        return f"{type(value).__name__}({', '.join(changed)})"
    return repr(value)


def _signature(function, *, drop_self: bool = False) -> str:
    """``(a: int, *, b: str = '') -> Path``: the annotations as written in the source (no quotes)."""
    signature = inspect.signature(function)
    parts, keyword_only = [], False
    for parameter in list(signature.parameters.values())[1 if drop_self else 0:]:
        if parameter.kind is parameter.KEYWORD_ONLY and not keyword_only:
            parts.append("*")
            keyword_only = True
        text = {parameter.VAR_POSITIONAL: "*", parameter.VAR_KEYWORD: "**"}.get(parameter.kind, "") + parameter.name
        keyword_only |= parameter.kind is parameter.VAR_POSITIONAL
        if parameter.annotation is not parameter.empty:
            text += f": {_annotation(parameter.annotation)}"
        if parameter.default is not parameter.empty:
            text += f" = {_short(parameter.default)}"
        parts.append(text)
    returns = signature.return_annotation
    shown = "" if returns is signature.empty or returns in (None, "None") else f" -> {_annotation(returns)}"
    return f"({', '.join(parts)}){shown}"


def _annotation(annotation) -> str:
    return annotation if isinstance(annotation, str) else inspect.formatannotation(annotation)


def _own_public_members(cls: type) -> list[tuple[str, object]]:
    members = []
    for name, value in vars(cls).items():
        if name.startswith("_") or not (inspect.isfunction(value) or isinstance(value, property | classmethod
                                                                                 | staticmethod)):
            continue
        members.append((name, value))
    return members


def python_section(target: str) -> str:
    """A class (signature, docstring, its own public methods and properties) or a function of the core.
    Only docstrings written here are shown, not those a method inherits (Gymnasium's, for the env)."""
    module, _, name = target.partition(":")
    obj = getattr(importlib.import_module(module), name)
    parts = [f"### `{module}.{name}`\n"]
    if inspect.isclass(obj):
        bases = [f"{b.__module__.split('.')[0]}.{b.__qualname__}" for b in obj.__bases__ if b is not object]
        parts.append(fenced(f"class {name}{'(' + ', '.join(bases) + ')' if bases else ''}\n"
                            f"{name}{_signature(obj.__init__, drop_self=True)}", "python"))
    else:
        parts.append(fenced(f"def {name}{_signature(obj)}", "python"))
    parts.append(inspect.cleandoc(obj.__doc__ or "") + "\n")
    if inspect.isclass(obj):
        for member, value in _own_public_members(obj):
            function = value.fget if isinstance(value, property) else getattr(value, "__func__", value)
            shown = "" if isinstance(value, property) else _signature(
                function, drop_self=not isinstance(value, staticmethod | classmethod) or isinstance(value, classmethod))
            doc = " ".join(inspect.cleandoc(function.__doc__ or "").split())
            kind = "property" if isinstance(value, property) else "method"
            parts.append(f"- `{member}{shown}` ({kind})" + (f": {doc}" if doc else ""))
        parts[-1] += "\n"
    return "\n".join(parts)


TOCTREE = re.compile(r"```\{toctree\}\n(?P<body>.*?)```", re.S)


def contents_list(page: Path) -> str:
    """The pages of the page's own toctree, each a link with its title."""
    found = TOCTREE.search(page.read_text())
    if not found:
        raise ConfigError(f"{_named(page)}: a contents block needs the page's toctree")
    names = []
    for entry in found.group("body").splitlines():
        entry = entry.strip()
        if not entry or entry.startswith(":"):
            continue
        matches = sorted(page.parent.glob(f"{entry}.md")) if "*" in entry else [page.parent / f"{entry}.md"]
        names += [m for m in matches if m != page]
    return "".join(f"- [{_title(target)}]({target.relative_to(page.parent).as_posix()})\n" for target in names)


GENERATORS = {
    "config": config_table, "topics": topic_table, "qos": qos_table, "launch": launch_table,
    "world-file": world_file_table, "messages": message_sections, "executables": executable_table,
    "commands": command_table, "help": help_block, "python": python_section, "contents": contents_list,
}


def generated(spec: str, page: Path) -> str:
    kind, *arguments = spec.split()
    if kind not in GENERATORS:
        raise ConfigError(f"{_named(page)}: unknown reference block {kind!r}; known: "
                          f"{', '.join(GENERATORS)}")
    return GENERATORS[kind](page) if kind == "contents" else GENERATORS[kind](*arguments)


def _named(page: Path) -> str:
    return page.relative_to(REPO_DIR).as_posix() if page.is_relative_to(REPO_DIR) else str(page)


def _title(page: Path) -> str:
    for line in page.read_text().splitlines():
        if line.startswith("# "):
            return line[2:].strip()
    raise ConfigError(f"{page} has no title (a '# ' heading) to link it by")


def linked(text: str, page: Path) -> str:
    """``{doc}`` and ``{repo}`` roles as relative Markdown links, which GitHub and MyST both follow."""

    def link(match: re.Match) -> str:
        target = match.group("target").strip()
        if match.group("role") == "doc":
            path = (page.parent / f"{target}.md").resolve()
            if not path.is_file():
                raise ConfigError(f"{_named(page)}: {{doc}} {target} is no page")
            return f"[{_title(path)}]({target}.md)"
        path, _, anchor = target.partition("#")
        if not (REPO_DIR / path).exists():
            raise ConfigError(f"{_named(page)}: repository path {path} does not exist")
        relative = os.path.relpath(REPO_DIR / path, page.parent) + ("/" if path.endswith("/") else "")
        return f"[{code(target)}]({relative}{'#' + anchor if anchor else ''})"

    return ROLE.sub(link, text)


def rendered(page: Path) -> str:
    """The page as it should be committed: its generated blocks and links written."""
    text = linked(page.read_text(), page)
    return BLOCK.sub(lambda m: m.group(1) + "\n" + generated(m.group("spec"), page) + "\n" + m.group(4), text)


def pages(root: Path = DOCS) -> list[Path]:
    return sorted(p for p in root.rglob("*.md") if "_build" not in p.relative_to(root).parts)


@reports_errors("make_reference")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="exit 1 naming each page that is not as generated")
    args = parser.parse_args(argv)
    stale = []
    for page in pages():
        text = rendered(page)
        if text != page.read_text():
            stale.append(page.relative_to(REPO_DIR).as_posix())
            if not args.check:
                page.write_text(text)
    if args.check and stale:
        print("not as generated (run python scripts/make_reference.py):\n  " + "\n  ".join(stale), file=sys.stderr)
        return 1
    for name in stale:
        print(f"wrote {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
