"""The generated parts of the docs (reference tables, --help texts, the Python API, links) are committed
as plain Markdown, so GitHub shows them; scripts/make_reference.py writes them and these tests fail when
a committed page is not what it writes from today's code."""

import dataclasses

import pytest

from m2h_ros import node_configs
from m2h_ros.paths import REPO_DIR
from scripts_as_modules import load_script

DOCS = REPO_DIR / "docs"


@pytest.fixture(scope="module")
def reference():
    return load_script("make_reference")


def test_every_committed_page_is_as_generated(reference, capsys):
    assert reference.main(["--check"]) == 0, capsys.readouterr().err


def test_no_page_names_the_checkout_it_was_written_in():
    # A page that quotes an absolute path reads differently in every clone, and --check fails there.
    pages = [page for page in DOCS.rglob("*.md") if str(REPO_DIR) in page.read_text()]
    assert not pages, [str(page.relative_to(REPO_DIR)) for page in pages]


def test_a_stale_table_and_a_sphinx_role_are_rewritten(reference, tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Page\n\nSee {repo}`m2h_ros/node_configs.py` and {doc}`index`.\n\n"
                    "<!-- reference: config m2h_ros.node_configs.SimConfig -->\n| stale |\n<!-- reference: end -->\n")
    (tmp_path / "index.md").write_text("# The index\n")
    text = reference.rendered(page)
    assert "| stale |" not in text and "{repo}" not in text and "{doc}" not in text
    assert "[The index](index.md)" in text
    linked = text.split("See [`m2h_ros/node_configs.py`](", 1)[1].split(")", 1)[0]
    assert (page.parent / linked).resolve() == REPO_DIR / "m2h_ros" / "node_configs.py"
    for field in dataclasses.fields(node_configs.SimConfig):
        assert f"| `{field.name}` |" in text, field.name
    page.write_text(text)
    assert reference.rendered(page) == text  # written once, fresh after


def test_a_missing_path_or_page_is_named(reference, tmp_path):
    page = tmp_path / "page.md"
    for role, message in (("{repo}`scripts/no_such_script.py`", "no_such_script.py does not exist"),
                          ("{doc}`no_such_page`", "no_such_page is no page")):
        page.write_text(f"# Page\n\n{role}\n")
        with pytest.raises(reference.ConfigError, match=message):
            reference.rendered(page)


def test_the_reference_covers_every_node_executable_and_launch_file():
    nodes_page = (DOCS / "reference" / "nodes.md").read_text()
    configs = [cls for cls in vars(node_configs).values()
               if dataclasses.is_dataclass(cls) and cls.__module__ == node_configs.__name__
               and issubclass(cls, node_configs.Config)]
    for cls in configs:
        assert f"<!-- reference: config m2h_ros.node_configs.{cls.__name__} -->" in nodes_page, cls.__name__
    commands_page = (DOCS / "reference" / "commands.md").read_text()
    for launch_file in (REPO_DIR / "launch").glob("*.launch.py"):
        assert f"<!-- reference: launch launch/{launch_file.name} -->" in commands_page
        assert f"`ros2 launch m2h_ros {launch_file.name}`" in commands_page
    for executable in ("m2h-eval", "m2h-separate", "base_node", "episode_driver", "capture_node",
                       "audio_common_adapter", "live_view_node"):
        assert f"`{executable}`" in commands_page or f"m2h_ros {executable}`" in commands_page, executable
