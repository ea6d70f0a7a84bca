"""The scripted startup under faults: a node killed mid-run ends the run at once (not after the
simulator's step timeout), exit 1, every node's exit code printed; a bad --set value, a mistyped
parameter name or a missing file is refused before any node starts. A node started alone refuses a
parameter it does not have, naming the nearest one, and a node started by a launch stops when the launch
process dies."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pipeline_helpers import ROOT, node_args, node_env, run_pipeline, tiny_sets

from m2h_ros.node_configs import NODE_CONFIGS

pytestmark = pytest.mark.graph
STEP_TIMEOUT_S = 60.0  # what a run that waited for the simulator's verdict would wait out


def marked_pid(marker: str, node: str) -> int | None:
    """The process of ``node`` started with ``marker`` in its environment (this test's run only)."""
    for proc in Path("/proc").iterdir():
        try:
            if (proc.name.isdigit() and marker.encode() in (proc / "environ").read_bytes()
                    and node.encode() in (proc / "cmdline").read_bytes()
                    and b"run_pipeline" not in (proc / "cmdline").read_bytes()):
                return int(proc.name)
        except OSError:
            pass
    return None


def test_a_node_killed_mid_run_ends_the_run_at_once_naming_it(small_library, small_data_dir, tmp_path):
    marker = f"faults-{os.getpid()}-{time.monotonic_ns()}"
    env = {**node_env(small_data_dir), "M2H_TEST_MARKER": marker}
    run = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--out", str(tmp_path),
                            "--episodes", "40", "--controller", "doa", "--step-timeout", str(STEP_TIMEOUT_S),
                            *tiny_sets()], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                           cwd=ROOT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "scores" / "results.json").exists():  # the run is under way
            assert run.poll() is None and time.monotonic() < deadline, run.communicate()
            time.sleep(0.1)
        pid = marked_pid(marker, "separator_node")
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        killed = time.monotonic()
        out, err = run.communicate(timeout=STEP_TIMEOUT_S + 30)
        ended_after = time.monotonic() - killed
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == 1, out + err
    assert "separator_node exited during the run: stopping every node" in out
    # Well inside the step timeout a run waiting for the simulator's verdict would sit out.
    assert ended_after < STEP_TIMEOUT_S / 2, out
    for node in NODE_CONFIGS:
        if node != "live_view_node":  # started only with --live-view
            assert f"[run]   {node:16s} exit " in out, out
    assert f"[run]   {'separator_node':16s} exit -9" in out
    assert "separator_node (exit -9)" in err


@pytest.mark.parametrize(("setting", "named"), [
    ("sim_node.num_episodes=0", "SimConfig.num_episodes = 0: must be >= 1"),
    ("controller_node.policy=no_such_policy", "ControllerConfig.policy = 'no_such_policy': must be one of"),
    ("separator_node.torch_threads=many", "SeparatorNodeConfig.torch_threads = 'many': expected int"),
    ("recorder_node.no_such_parameter=1", "unknown RecorderConfig setting(s)"),
    ("sim_node.num_episode=1", "num_episode (did you mean num_episodes?)"),
    ("sim_node.head=sofa:/nonexistent.sofa", "SimConfig.head = '/nonexistent.sofa': no such file"),
    ("controller_node.checkpoint=/nonexistent.pt", "ControllerConfig.checkpoint = '/nonexistent.pt': no such file"),
])
def test_a_bad_set_value_is_refused_before_any_node_starts(setting, named, small_data_dir, tmp_path):
    result = run_pipeline(tmp_path, small_data_dir, "--set", setting, timeout=60)
    assert result.returncode == 1
    assert named in result.stderr, result.stderr
    assert not (tmp_path / "logs").exists()  # no node was started


def test_a_mistyped_parameter_of_a_node_is_an_error_naming_the_nearest_one(processes):
    """rclpy drops a value for a parameter nobody declared: the node ran on its defaults without a word."""
    proc = processes.start(node_args("sim_node", num_episode=1))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err
    assert "unknown parameter(s) of sim_node: num_episode (did you mean num_episodes?)" in err


def test_a_node_started_by_a_launch_stops_when_the_launch_process_dies(processes, tmp_path):
    """The launch files hand their nodes the launch process's id: however the launch ends (here SIGKILL,
    which it cannot catch), its nodes stop cleanly instead of joining the next run's graph."""
    bag = tmp_path / "bag"
    launcher = processes.start([sys.executable, "-c", (
        "import os, subprocess, sys\n"
        "env = {**os.environ, 'M2H_STOP_WITH_PARENT': str(os.getpid())}\n"
        f"node = subprocess.Popen({node_args('recorder_node', output=str(bag))!r}, env=env)\n"
        "print(node.pid, flush=True)\n"
        "node.wait()\n")])
    pid = int(launcher.stdout.readline())
    for line in launcher.stderr:  # the node is up (its log goes to the launcher's stderr)
        if "recording to" in line:
            break

    def node_running() -> bool:
        try:
            return b"recorder_node" in Path(f"/proc/{pid}/cmdline").read_bytes()  # a zombie's is empty
        except OSError:
            return False

    launcher.kill()
    try:
        deadline = time.monotonic() + 20
        while node_running():
            assert time.monotonic() < deadline, "the node outlived its launch"
            time.sleep(0.1)
    finally:
        if node_running():
            os.kill(pid, signal.SIGKILL)
    assert (bag / "metadata.yaml").exists()  # it stopped as on Ctrl-C: the bag closed
