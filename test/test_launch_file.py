"""The launch file (for machines with `ros2 launch`, which this venv lacks) parses, starts every
node of the pipeline with its params file, and is installed with the package."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch" / "pipeline.launch.py"


def test_launch_file_starts_every_node_with_its_params():
    tree = ast.parse(LAUNCH.read_text())
    functions = {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}
    assert "generate_launch_description" in functions
    nodes = next(node for node in ast.walk(tree) if isinstance(node, ast.Assign)
                 and getattr(node.targets[0], "id", "") == "NODES")
    names = {element.value for element in nodes.value.elts}
    assert names == {p.stem for p in (ROOT / "params").glob("*.yaml")}
    for name in names:
        assert (ROOT / "m2h_ros" / "nodes" / f"{name}.py").is_file()
    assert 'glob("launch/*.launch.py")' in (ROOT / "setup.py").read_text()
