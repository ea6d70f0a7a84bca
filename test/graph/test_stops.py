"""How a run is stopped from a terminal: Ctrl-C pressed twice or held. A terminal sends SIGINT to its
whole foreground process group, and ros2 launch forwards it to every node once more, so each node gets
it again while it is already shutting down. Whatever the repeats, every node exits 0 without a
traceback, the bag is closed (footer and metadata.yaml) and the evaluator's tables and plot are written.

Both startups: run_pipeline.py (its nodes in sessions of their own: the terminal reaches only the
script, a user's kill -INT reaches the nodes too), and the nodes in one process group as ros2 launch
starts them (a stand-in where ros2 launch is not installed)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pipeline_helpers import ROOT, TINY_SIM, bag_messages, node_args, node_env, tiny_sets

pytestmark = pytest.mark.graph
HELD_FOR_S = 3.0  # a held Ctrl-C: the terminal's key repeat sends SIGINT about every 30 ms
REPEAT_S = 0.03
NODES = ("recorder_node", "evaluator_node", "separator_node", "controller_node", "sim_node")


def marked_pids(marker: str) -> dict[int, str]:
    """pid -> node name of the processes started with ``marker`` in their environment."""
    found = {}
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and marker.encode() in (proc / "environ").read_bytes():
                cmdline = (proc / "cmdline").read_bytes().split(b"\0")
                name = next((n for n in NODES if any(part.endswith(n.encode()) for part in cmdline)), None)
                if name is not None and b"run_pipeline" not in b" ".join(cmdline):
                    found[int(proc.name)] = name
        except OSError:
            pass
    return found


def wait_until_scored(out: Path, alive, what: str) -> None:
    deadline = time.monotonic() + 120
    while not (out / "scores" / "results.json").exists():  # every node at work: an episode is scored
        assert alive() and time.monotonic() < deadline, f"{what} never got going"
        time.sleep(0.1)


def hold_ctrl_c(send, done) -> int:
    """SIGINT through ``send()`` every REPEAT_S for HELD_FOR_S or until ``done()``; returns how many."""
    sent = 0
    until = time.monotonic() + HELD_FOR_S
    while time.monotonic() < until and not done():
        send()
        sent += 1
        time.sleep(REPEAT_S)
    return sent


def check_closed(out: Path) -> None:
    """The bag has its footer and metadata.yaml, and the evaluator wrote its tables and plot."""
    from mcap.reader import make_reader

    bag = out / "bag"
    assert (bag / "metadata.yaml").exists()
    (mcap,) = bag.glob("*.mcap")
    with mcap.open("rb") as stream:
        assert make_reader(stream).get_summary() is not None  # the summary and footer were written
    assert len(bag_messages(bag)["/audio"]) > 0
    for name in ("results.md", "results.json", "si_sdr_vs_step.png"):
        assert (out / "scores" / name).exists(), name


def test_ctrl_c_held_under_run_pipeline_leaves_a_closed_bag_and_every_node_exit_0(small_library, small_data_dir,
                                                                                  tmp_path):
    """SIGINT to the script and to every node, again and again, as a held Ctrl-C and a user's
    kill -INT of every process do."""
    marker = f"stops-{os.getpid()}-{time.monotonic_ns()}"
    env = {**node_env(small_data_dir), "M2H_TEST_MARKER": marker}
    run = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--out", str(tmp_path),
                            "--episodes", "40", "--controller", "doa", *tiny_sets()],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
                           start_new_session=True)
    try:
        wait_until_scored(tmp_path, lambda: run.poll() is None, "the run")
        pids = [run.pid, *marked_pids(marker)]
        assert len(pids) == 1 + len(NODES)

        def send() -> None:
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGINT)
                except ProcessLookupError:
                    pass

        assert hold_ctrl_c(send, lambda: run.poll() is not None) > 1
        out, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == 130, out + err  # interrupted, and every node exited cleanly
    for node in NODES:
        assert f"[run]   {node:16s} exit 0" in out, out
    logs = {log.name: log.read_text() for log in (tmp_path / "logs").iterdir()}
    assert not [name for name, text in logs.items() if "Traceback" in text], logs
    assert "Traceback" not in err, err
    check_closed(tmp_path)
    # The tables say the run is partial, in the file and in what run_pipeline prints.
    title = (tmp_path / "scores" / "results.md").read_text().splitlines()[0]
    assert re.fullmatch(r"# m2h_ros pipeline run \(partial: \d+ of 40 episodes scored, the run ended early\)", title)
    assert title in out


def test_ctrl_c_held_in_one_process_group_as_ros2_launch_starts_them(small_library, small_data_dir, tmp_path):
    """The nodes in one process group (ros2 launch's children): the group gets SIGINT again and again."""
    env = node_env(small_data_dir)
    nodes = {"recorder_node": dict(output=str(tmp_path / "bag")),
             "evaluator_node": dict(output_dir=str(tmp_path / "scores")),
             "separator_node": {}, "controller_node": dict(policy="doa"),
             "sim_node": {**TINY_SIM, "num_episodes": 40, "expect_nodes": list(NODES[:-1])}}
    procs: dict[str, subprocess.Popen] = {}
    try:
        for name, params in nodes.items():
            group = procs["recorder_node"].pid if procs else 0  # 0: a new group, led by the recorder
            procs[name] = subprocess.Popen(node_args(name, **params), stdout=subprocess.PIPE,
                                           stderr=subprocess.PIPE, text=True, env=env, process_group=group)
        group = procs["recorder_node"].pid
        wait_until_scored(tmp_path, lambda: all(p.poll() is None for p in procs.values()), "the graph")
        assert hold_ctrl_c(lambda: os.killpg(group, signal.SIGINT),
                           lambda: all(p.poll() is not None for p in procs.values())) > 1
        outputs = {name: proc.communicate(timeout=30) for name, proc in procs.items()}
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for name, proc in procs.items():
        assert proc.returncode == 0, (name, proc.returncode, outputs[name][1][-3000:])
        assert "Traceback" not in outputs[name][1], (name, outputs[name][1])
    check_closed(tmp_path)
