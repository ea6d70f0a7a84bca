"""Write the example imported worlds the docs, the results and the tests use (deterministic: the same
bytes every run; docs/worlds/ holds the committed copy, and a test checks it is what this writes).

    python scripts/make_example_worlds.py --out docs/worlds

* ``apartment/map.yaml`` + ``map.pgm``: a 12 x 9 m six-room flat as a robot's SLAM map saved by
  ``map_saver_cli`` (ragged walls, specks; 5 cm cells), with no world file: every setting at its default;
* ``generated_mesh/test_000.glb``: the first generated test scene exported as a mesh (glTF, y up);
* ``turned_mesh/test_000_turned.glb``: the same scene turned 30 degrees: no wall on a lattice axis.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from pathlib import Path

from m2h_ros.core.world.mesh_camera import scene_mesh
from m2h_ros.core.world.ros_map import write_ros_map
from m2h_ros.core.world.sample_worlds import apartment_grid
from m2h_ros.core.world.scene import load_split
from m2h_ros.errors import reports_errors

APARTMENT_NOISE = 0.3
TURN_DEG = 30.0
WORLDS = {"apartment": "map:apartment/map.yaml", "generated_mesh": "mesh:generated_mesh/test_000.glb",
          "turned_mesh": "mesh:turned_mesh/test_000_turned.glb"}


def _export_module():
    spec = importlib.util.spec_from_file_location("export_scene_mesh", Path(__file__).with_name("export_scene_mesh.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_examples(out: Path) -> dict[str, str]:
    """Write every example world under ``out``; name -> its world spec."""
    export = _export_module()
    write_ros_map(out / "apartment" / "map.yaml", apartment_grid(noise=APARTMENT_NOISE))
    mesh = scene_mesh(load_split("test")[0])
    for path, data in ((out / "generated_mesh" / "test_000.glb", export.export_bytes(mesh, "glb")),
                       (out / "turned_mesh" / "test_000_turned.glb",
                        export.export_bytes(export.turned(mesh, TURN_DEG), "glb"))):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    return {name: f"{spec.split(':')[0]}:{out / spec.split(':', 1)[1]}" for name, spec in WORLDS.items()}


@reports_errors("make_example_worlds")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder to write the worlds into")
    args = parser.parse_args(argv)
    for name, spec in write_examples(args.out).items():
        print(f"{name}: {spec}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
