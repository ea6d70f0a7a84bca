"""ament_python package m2h_ros: installs the nodes where `ros2 run m2h_ros <node>` finds them."""

from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.develop import develop
from setuptools.command.install_scripts import install_scripts

from m2h_ros.nodes.entry import NODES

PACKAGE = "m2h_ros"
CONSOLE_SCRIPTS = {**{node: f"{PACKAGE}.nodes.entry:{node}" for node in NODES},
                   "m2h-separate": "m2h_ros.separate_cli:main", "m2h-eval": "m2h_ros.replay_cli:main",
                   "m2h-derive": "m2h_ros.derive_cli:main"}
# setuptools' console scripts first scan every installed distribution's metadata for their entry point
# (about 40 ms in this venv, in which a Ctrl-C printed a traceback); these import it directly.
DIRECT_SCRIPT = """# {name}: the {package} console script, importing its entry point directly.
import sys

from {module} import {attribute}

if __name__ == "__main__":
    sys.exit({attribute}())
"""


def write_direct_scripts(folder: str) -> None:
    """Replace the body of each console script setuptools wrote into ``folder``, keeping its #! line."""
    for name, target in CONSOLE_SCRIPTS.items():
        path = Path(folder) / name
        if path.is_file():
            module, attribute = target.split(":")
            shebang = path.read_text().splitlines()[0]
            path.write_text(shebang + "\n" + DIRECT_SCRIPT.format(name=name, package=PACKAGE, module=module,
                                                                   attribute=attribute))


class DevelopWithDirectScripts(develop):  # colcon build --symlink-install
    def install_wrapper_scripts(self, dist):
        super().install_wrapper_scripts(dist)
        write_direct_scripts(self.script_dir)


class InstallDirectScripts(install_scripts):  # colcon build
    def run(self):
        super().run()
        write_direct_scripts(self.install_dir)


setup(
    name=PACKAGE,
    version="1.0.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["models/default/*.pt", "models/default/*.json", "core/sounds/library_index.json",
                           "io/virtual_mic.c"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/params", glob("params/*.yaml") + glob("params/*.xml") + glob("params/*.json")),
        (f"share/{PACKAGE}/params/recipes", glob("params/recipes/*")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="m2h_ros developers",
    maintainer_email="m2h-ros@example.org",
    description="Active audio-visual source separation (Move2Hear) as a ROS 2 node suite",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in CONSOLE_SCRIPTS.items()]},
    cmdclass={"develop": DevelopWithDirectScripts, "install_scripts": InstallDirectScripts},
)
