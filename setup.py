"""ament_python package m2h_ros: installs the nodes where `ros2 run m2h_ros <node>` finds them."""

from glob import glob

from setuptools import find_packages, setup

from m2h_ros.nodes.entry import NODES

PACKAGE = "m2h_ros"

setup(
    name=PACKAGE,
    version="1.0.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["models/default/*.pt", "models/default/*.json", "core/sounds/library_index.json",
                           "io/virtual_mic.c"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/params", glob("params/*.yaml") + glob("params/*.xml")),
        (f"share/{PACKAGE}/params/recipes", glob("params/recipes/*")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="m2h_ros developers",
    maintainer_email="m2h-ros@example.org",
    description="Active audio-visual source separation (Move2Hear) as a ROS 2 node suite",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{node} = {PACKAGE}.nodes.entry:{node}" for node in NODES]
        + ["m2h-separate = m2h_ros.separate_cli:main", "m2h-eval = m2h_ros.replay_cli:main"],
    },
)
