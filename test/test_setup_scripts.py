"""The set-up scripts: setup.sh takes Python 3.11 or 3.12 only; setup_distro.sh against a stand-in for
/opt/ros/jazzy: a venv that sees the distro's packages and that colcon ignores, the non-ROS pins, colcon
run by the venv's Python, and an env.sh that brings it all together. The pip step and the smoke check of
the real libraries are stood in for; they need a real Jazzy. Nothing here depends on which Pythons the
machine has: the other versions are this interpreter answering with another version, and the system's
Python is the interpreter this venv was made from, alone on PATH."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from m2h_ros.paths import REPO_DIR

SETUP = REPO_DIR / "scripts" / "setup.sh"
DISTRO = REPO_DIR / "scripts" / "setup_distro.sh"
# A Python of another version as setup.sh sees it: this interpreter, reporting that version.
_OTHER_VERSION = """#!{executable}
import sys
sys.version_info = ({major}, {minor}, 0, "final", 0)
if sys.argv[1:2] == ["-c"]:
    code, sys.argv = sys.argv[2], ["-c", *sys.argv[3:]]
    exec(code)
"""


def _interpreter(version: str, folder: Path) -> Path:
    major, minor = version.split(".")
    path = folder / f"python{version}_stand_in"
    path.write_text(_OTHER_VERSION.format(executable=sys.executable, major=major, minor=minor))
    path.chmod(0o755)
    return path


@pytest.mark.parametrize("version", ["3.10", "3.13"])
def test_setup_refuses_pythons_the_ros_wheels_are_not_built_for(version, tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    wrong = _interpreter(version, tmp_path)
    for name in ("python3", "python3.11", "python3.12"):  # every candidate is the wrong one
        (bin_dir / name).symlink_to(wrong)
    # A copy outside the repository: were a wrong Python accepted, the set-up would stop at once in an
    # empty folder instead of installing into the repository.
    (tmp_path / "scripts").mkdir()
    shutil.copy(SETUP, tmp_path / "scripts" / "setup.sh")
    env = {**os.environ, "PATH": f"{bin_dir}:/bin", "M2H_PYTHON": ""}
    done = subprocess.run(["bash", str(tmp_path / "scripts" / "setup.sh")], env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 1
    assert "Python 3.11 or 3.12 not found" in done.stderr


# ----------------------------------------------------------------------------- the distro recipe

_FAKE_COLCON = '''
import json, os, sys
from pathlib import Path
Path("colcon_call.json").write_text(json.dumps({"executable": sys.executable, "argv": sys.argv[1:],
    "cwd": os.getcwd(), "virtual_env": os.environ.get("VIRTUAL_ENV")}))
Path("install").mkdir(exist_ok=True)
Path("install/setup.bash").write_text("export M2H_TEST_WORKSPACE_SOURCED=1\\n")
'''


@pytest.fixture
def stand_in_ros(tmp_path):
    """A /opt/ros/jazzy stand-in: setup.bash sets ROS_DISTRO and puts rclpy and colcon on PYTHONPATH,
    as the real one does; colcon records how it was run."""
    root = tmp_path / "opt_ros_jazzy"
    site = root / "lib" / "python3" / "site-packages"
    for package, text in (("rclpy", ""), ("colcon_core", ""), ("colcon", ""), ("sensor_msgs", "")):
        (site / package).mkdir(parents=True)
        (site / package / "__init__.py").write_text(text)
    (site / "colcon" / "__main__.py").write_text(_FAKE_COLCON)
    (root / "setup.bash").write_text(f'export ROS_DISTRO=jazzy\nexport PYTHONPATH="{site}${{PYTHONPATH:+:$PYTHONPATH}}"\n')
    return root / "setup.bash"


# The system's Python of a fresh robot: one with no ROS and outside any venv (this venv's base interpreter).
DISTRO_PYTHON = Path(sys._base_executable).resolve()
SYSTEM_BIN: list[Path] = []  # a folder holding only python3 (the system's), made once per session


@pytest.fixture(scope="module", autouse=True)
def _system_bin(tmp_path_factory):
    folder = tmp_path_factory.mktemp("system_bin")
    (folder / "python3").symlink_to(DISTRO_PYTHON)
    SYSTEM_BIN[:] = [folder]


def _clean_env(setup: Path) -> dict[str, str]:
    """No venv, no PYTHONPATH: the shell of a robot whose only Python is the system's, first on PATH."""
    return {"PATH": f"{SYSTEM_BIN[0]}:/usr/bin:/bin", "HOME": os.environ["HOME"], "M2H_ROS_SETUP": str(setup)}


def _distro(script: str, setup: Path, *, cwd: Path) -> subprocess.CompletedProcess:
    """Run bash with setup_distro.sh sourced (its steps defined), the pip step and the real-library
    check stood in for, then ``script``."""
    prelude = f"""
        . "{DISTRO}"
        install_pins() {{ distro_requirements > "$1/pins.txt"; echo "$VENV_PY" > "$1/pins_python"; }}
        fetch_sources() {{ :; }}
        check_install() {{ :; }}
    """
    return subprocess.run(["bash", "-c", prelude + script], env=_clean_env(setup), cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def test_the_distro_recipe_builds_a_workspace_with_a_venv_that_sees_the_distro(stand_in_ros, tmp_path):
    ws = tmp_path / "ws"
    done = _distro(f'main "{ws}"', stand_in_ros, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    venv_python = ws / "venv" / "bin" / "python"
    # A venv of the distro's Python that sees its packages, and that colcon does not crawl.
    assert "include-system-site-packages = true" in (ws / "venv" / "pyvenv.cfg").read_text()
    assert (ws / "venv" / "COLCON_IGNORE").is_file()
    seen = subprocess.run([str(venv_python), "-c", "import sys; print('\\n'.join(sys.path))"],
                          env=_clean_env(stand_in_ros), capture_output=True, text=True, check=True).stdout.split()
    system = subprocess.run([str(DISTRO_PYTHON), "-c", "import site; print('\\n'.join(site.getsitepackages()))"],
                            capture_output=True, text=True, check=True).stdout.split()
    # Where apt puts python3-* modules (/usr/lib/python3/dist-packages on Debian); site lists directories
    # that may not exist on this machine, and sys.path leaves those out.
    system = [path for path in system if Path(path).is_dir()]
    assert system and set(system) <= set(seen)
    # The pins go into the venv, without the ROS wheels, colcon or the setuptools pin.
    assert (ws / "pins_python").read_text().strip() == str(venv_python)
    pins = (ws / "pins.txt").read_text().split("\n")
    assert "torch==2.13.0" in pins and "sofar==1.3.0" in pins
    assert not [p for p in pins if p.startswith(("ros-jazzy-", "colcon", "setuptools"))]
    wanted = [line for line in (REPO_DIR / "requirements.txt").read_text().split("\n")
              if not line.startswith(("ros-jazzy-", "colcon", "setuptools"))]
    assert pins == wanted
    # The repository is the workspace's source; colcon ran with the venv's Python and CMake is told so.
    assert (ws / "src" / "m2h_ros").resolve() == REPO_DIR.resolve()
    assert (ws / "src" / "m2h_msgs").resolve() == (REPO_DIR / "msg_defs").resolve()
    call = json.loads((ws / "colcon_call.json").read_text())
    assert call["executable"] == str(venv_python)
    assert call["virtual_env"] == str(ws / "venv")
    assert Path(call["cwd"]) == ws
    assert call["argv"][:1] == ["build"] and "--symlink-install" in call["argv"]
    assert f"-DPython3_EXECUTABLE={venv_python}" in call["argv"]
    # env.sh: the distro, the workspace and the venv, in that order.
    shown = subprocess.run(["bash", "-c", f'. "{ws}/env.sh"; echo "$ROS_DISTRO $M2H_TEST_WORKSPACE_SOURCED '
                                          f'$(command -v python) $FASTRTPS_DEFAULT_PROFILES_FILE"'],
                           env=_clean_env(stand_in_ros), capture_output=True, text=True)
    assert shown.stdout.split() == ["jazzy", "1", str(ws / "venv" / "bin" / "python"),
                                    str(REPO_DIR / "params" / "fastdds.xml")]
    # A second run finds everything in place.
    assert _distro(f'main "{ws}"', stand_in_ros, cwd=tmp_path).returncode == 0


def test_the_distro_recipe_says_what_is_missing(stand_in_ros, tmp_path):
    missing = _distro(f'main "{tmp_path}/ws"', tmp_path / "none" / "setup.bash", cwd=tmp_path)
    assert missing.returncode == 1 and "no ROS 2 at" in missing.stderr
    humble = tmp_path / "humble.bash"
    humble.write_text(stand_in_ros.read_text().replace("ROS_DISTRO=jazzy", "ROS_DISTRO=humble"))
    assert "this recipe is for jazzy" in _distro(f'main "{tmp_path}/ws"', humble, cwd=tmp_path).stderr
    no_rclpy = tmp_path / "no_rclpy"
    shutil.copytree(stand_in_ros.parent, no_rclpy)
    shutil.rmtree(no_rclpy / "lib" / "python3" / "site-packages" / "rclpy")
    (no_rclpy / "setup.bash").write_text(stand_in_ros.read_text().replace(str(stand_in_ros.parent), str(no_rclpy)))
    assert "cannot import rclpy" in _distro(f'main "{tmp_path}/ws"', no_rclpy / "setup.bash", cwd=tmp_path).stderr
    plain = tmp_path / "plain"
    subprocess.run([str(DISTRO_PYTHON), "-m", "venv", "--without-pip", str(plain / "venv")], check=True)
    refused = _distro(f'main "{plain}"', stand_in_ros, cwd=tmp_path)
    assert refused.returncode == 1 and "without --system-site-packages" in refused.stderr
