"""The five nodes as real processes: a whole recorded and scored run, its equivalence with the
in-process evaluation, and the faults (a node killed mid-run, bad parameters, bad messages)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from known_mixture import SEPARATION_FLOOR_DB
from pipeline_helpers import ROOT, TINY_SIM, bag_messages, node_args, node_env, run_pipeline, tiny_sets

from m2h_ros import sim_world, topics
from m2h_ros.core.results import read_results
from m2h_ros.core.world.episodes import DEFAULT_MAX_STEPS, STOP
from m2h_ros.io.derived import derived_topics
from m2h_ros.node_configs import SimConfig

pytestmark = pytest.mark.graph
CONTROLLER = "random"  # stochastic: the equivalence test then also covers the per-episode seeding


@pytest.fixture(scope="module")
def tiny_run(small_library, small_data_dir, tmp_path_factory):
    """One 2-episode run of the whole pipeline on the tiny setup (shared by the checks below), its bag's
    chunks zstd-compressed: the replay and the Foxglove checks below read them."""
    out = tmp_path_factory.mktemp("run")
    result = run_pipeline(out, small_data_dir, "--episodes", "2", "--controller", CONTROLLER,
                          "--set", "controller_node.seed=7", "--compression", "zstd", *tiny_sets())
    assert result.returncode == 0, result.stdout + result.stderr
    return out, result


def test_run_reports_where_everything_is(tiny_run):
    out, result = tiny_run
    for what in ("scores :", "plot   :", "bag    :"):
        assert what in result.stdout
    assert f"| {CONTROLLER} | near_target | unheard | 2 |" in result.stdout
    for name in ("results.md", "results.csv", "results.json", "si_sdr_vs_step.png"):
        assert (out / "scores" / name).stat().st_size > 0
    assert (out / "scores" / "results.md").read_text().startswith("# m2h_ros pipeline run\n")  # whole: not partial
    # The evaluator prints the table itself (under ros2 launch its output is what a user sees)
    assert f"| {CONTROLLER} | near_target | unheard | 2 |" in (out / "logs" / "evaluator_node.log").read_text()


def test_bag_holds_every_topic_with_contiguous_steps(tiny_run, small_library):
    out, _ = tiny_run
    messages = bag_messages(out / "bag")
    expected = {f"/{t}" if not t.startswith("/") else t for t in
                (topics.AUDIO, topics.RGB, topics.DEPTH, topics.CAMERA_INFO, topics.ODOM, topics.AGENT_POSE,
                 topics.EPISODE, topics.GROUND_TRUTH, topics.SEPARATED_BINAURAL, topics.MONAURAL, topics.REFINED,
                 topics.SEPARATED_AUDIO, topics.COMMAND, topics.STEP_SCORE, topics.EPISODE_SCORE)}
    assert expected <= set(messages)
    episodes = [m.episode_id for m in messages["/episode"]]
    config = SimConfig(**TINY_SIM, num_episodes=2)
    planned = sim_world.sim_episodes(config, small_library)
    assert episodes == [e.episode_id for e in planned]
    for topic in ("/audio", "/ground_truth/target", "/separator/refined", "/scores/step"):
        for episode in planned:
            steps = [m.step for m in messages[topic] if m.episode_id == episode.episode_id]
            assert steps == list(range(episode.max_steps + 1)), (topic, steps)
    for episode in planned:  # one command per step except the last observation
        steps = [m.step for m in messages["/cmd"] if m.episode_id == episode.episode_id]
        assert steps == list(range(episode.max_steps))
    # Standard messages are tied to their step by the stamp the audio frame carries.
    assert [m.header.stamp for m in messages["/odom"]] == [m.header.stamp for m in messages["/audio"]]
    image = messages["/camera/rgb/image_raw"][0]
    assert (image.encoding, image.height, image.width, len(image.data)) == ("rgb8", 32, 32, 32 * 32 * 3)
    assert messages["/camera/depth/image_raw"][0].encoding == "32FC1"
    assert len(messages["/scores/episode"]) == 2


def assert_equals_in_process(out: Path, sim: dict, controller: str, seed: int, library) -> None:
    """The graph run in ``out`` against the same episodes, controller and seed in-process: same actions,
    same per-step scores (run with M2H_DATA_DIR at the graph run's data dir)."""
    import torch

    from m2h_ros.agents.registry import make_controller
    from m2h_ros.agents.rollout import evaluate_controller
    from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
    from m2h_ros.models.runner import SeparatorRunner

    torch.set_num_threads(1)
    config = SimConfig(**sim)
    episodes = sim_world.sim_episodes(config, library)
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    n = len(episodes)
    in_process = evaluate_controller(make_controller(controller, n, seed=seed), SeparatorRunner(loaded, n), episodes,
                                     library, env_config=sim_world.env_config(config), progress=False)
    graph = {r.episode_id: r for r in read_results(out / "scores" / "results.json")}
    assert len(graph) == n
    for local in in_process:
        remote = graph[local.episode_id]
        assert remote.actions == local.actions
        np.testing.assert_allclose(remote.si_sdr, local.si_sdr, atol=1e-3)
        np.testing.assert_allclose(remote.si_sdr_mixture_phase, local.si_sdr_mixture_phase, atol=1e-3)
        np.testing.assert_allclose(remote.stft_distance, local.stft_distance, rtol=1e-4)
        assert remote.path_length == pytest.approx(local.path_length)
        assert remote.shortest_path == pytest.approx(local.shortest_path)


def test_scores_equal_the_in_process_run(tiny_run, small_library, small_data_dir, monkeypatch):
    """Same episodes, controller and seed in-process: same actions, same per-step scores."""
    out, _ = tiny_run
    monkeypatch.setenv("M2H_DATA_DIR", str(small_data_dir))
    assert_equals_in_process(out, {**TINY_SIM, "num_episodes": 2}, CONTROLLER, 7, small_library)


# Far-target: tiny episode 10 is one the shipped pi^N + Stop ends with Stop, on the target's node (stage 5 from pi^Q;
# the twelve-stage chain's stages 9 and 12 too), so the Stop's path through the graph is exercised; a retrained pi^N
# may need another episode here.
@pytest.mark.parametrize("task, first", [("near_target", 0), ("far_target", 10)])
def test_the_default_controller_is_move2hear_and_acts_as_in_process(task, first, small_library, small_data_dir,
                                                                    tmp_path, monkeypatch):
    """The main job's controller (the params file's default) reads the camera and the separator's three
    estimates through the graph and chooses what it chooses in-process: near-target the shipped pi^Q,
    far-target the shipped pi^N + Stop, whose Stop ends the episode in both."""
    from m2h_ros.node_configs import ControllerConfig

    assert ControllerConfig().policy == "move2hear"
    sim = {**TINY_SIM, "camera_size": 64, "num_episodes": 1, "task": task,  # the compact policy's RGB size
           "first_episode": first}
    result = run_pipeline(tmp_path, small_data_dir, "--episodes", "1", "--task", task, "--first", str(first),
                          *tiny_sets(camera_size=64))
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"| move2hear | {task} | unheard | 1 |" in result.stdout
    monkeypatch.setenv("M2H_DATA_DIR", str(small_data_dir))
    assert_equals_in_process(tmp_path, sim, "move2hear", 0, small_library)
    if task == "far_target":
        (episode,) = read_results(tmp_path / "scores" / "results.json")
        assert episode.actions[-1] == STOP and len(episode.actions) < DEFAULT_MAX_STEPS[task] and episode.success, (
            f"tiny far-target episode {first} no longer ends with pi^N's Stop ({len(episode.actions)} actions): "
            "pick an episode where the shipped pi^N stops")


def start_graph(processes, data_dir, tmp_path, *, sim: dict, evaluator: bool = True,
                udp_only: tuple[str, ...] = ()):
    """The five nodes as processes; those named in ``udp_only`` talk over UDP alone, no shared memory."""
    env = node_env(data_dir)
    nodes = {"recorder_node": dict(output=str(tmp_path / "bag")),
             "separator_node": {}, "controller_node": dict(policy=CONTROLLER)}
    if evaluator:
        nodes["evaluator_node"] = dict(output_dir=str(tmp_path / "scores"))
    procs = {name: processes.start(node_args(name, **params),
                                   env={**env, "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"} if name in udp_only else env)
             for name, params in nodes.items()}
    sim_params = {**TINY_SIM, "expect_nodes": [n for n in nodes], **sim}
    procs["sim_node"] = processes.start(node_args("sim_node", **sim_params), env=env)
    return procs


def graph_subscribers(prefix: str, *, settled, timeout: float = 60.0) -> dict[str, set[str]]:
    """Topic -> names of the nodes subscribed to it, for the running graph's topics under ``prefix``, read
    by a probe node once ``settled(found, probe)`` is true (so a node still starting up is not taken for
    one that does not listen)."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        probe = rclpy.create_node("ground_truth_probe", context=context)
        deadline = time.monotonic() + timeout
        while True:
            found = {name: {info.node_name for info in probe.get_subscriptions_info_by_topic(name)}
                     for name, _ in probe.get_topic_names_and_types() if name.startswith(prefix)}
            if settled(found, probe):
                return found
            assert time.monotonic() < deadline, f"the graph never settled: {found}, nodes {probe.get_node_names()}"
            time.sleep(0.2)
    finally:
        rclpy.try_shutdown(context=context)


def test_only_the_evaluator_and_the_recorder_subscribe_to_the_ground_truth(processes, small_library, small_data_dir,
                                                                          tmp_path):
    """The controller never sees the ground truth: in the running graph, nothing but the evaluator (which
    scores) and the recorder (which keeps everything) subscribes to a topic under /ground_truth."""
    procs = start_graph(processes, small_data_dir, tmp_path, sim=dict(num_episodes=30))
    deadline = time.monotonic() + 120
    while not (tmp_path / "scores" / "results.json").exists():  # every node at work: an episode is scored
        if procs["sim_node"].poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"the run never got going: {procs['sim_node'].communicate()[1]}")
        time.sleep(0.1)

    derived = derived_topics()  # left to m2h-derive: nobody subscribes to them in an unwatched run

    def settled(found, probe) -> bool:  # the recorder on every raw topic, the evaluator on its own, the controller up
        return (topics.GROUND_TRUTH in found and "evaluator_node" in found[topics.GROUND_TRUTH]
                and all("recorder_node" in nodes for topic, nodes in found.items() if topic not in derived)
                and "controller_node" in probe.get_node_names()
                and bool(probe.get_subscriber_names_and_types_by_node("controller_node", "/")))

    subscribers = graph_subscribers("/ground_truth/", settled=settled)
    assert {name for nodes in subscribers.values() for name in nodes} == {"evaluator_node", "recorder_node"}


def test_killed_controller_is_named_and_the_bag_stays_readable(processes, small_library, small_data_dir, tmp_path):
    # Enough episodes that the run cannot end before the kill. The timeout leaves room for the separator's
    # publishes to stall after the kill (likely Fast DDS's shared-memory transport waiting on the dead
    # reader's port): with 3 s, a fresh-clone run once named separator_node instead.
    procs = start_graph(processes, small_data_dir, tmp_path, sim=dict(num_episodes=30, step_timeout_s=10.0))
    bag = tmp_path / "bag"
    deadline = time.monotonic() + 120
    while not (tmp_path / "scores" / "results.json").exists():  # the first episode is scored
        if procs["sim_node"].poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"the run never got going: {procs['sim_node'].communicate()[1]}")
        time.sleep(0.1)
    procs["controller_node"].send_signal(signal.SIGKILL)
    _, err = procs["sim_node"].communicate(timeout=60)
    assert procs["sim_node"].returncode == 2
    # (Its name may linger in discovery for a few seconds after SIGKILL, so only the diagnosis is checked.)
    assert "no motion command for" in err and "controller_node did not answer" in err
    code, _, _ = processes.interrupt(procs["recorder_node"])
    assert code == 0
    messages = bag_messages(bag)
    assert len(messages["/audio"]) > len(messages.get("/cmd", []))


def test_a_stalled_evaluator_holds_the_sim_within_its_lag_and_is_named(processes, small_library, small_data_dir,
                                                                          tmp_path):
    lag = 8
    # The step timeout is no speed limit: on busy cores a live node may take seconds to answer a step, and
    # the diagnosis must name the stalled evaluator, not whichever node was slow.
    # SIGSTOP freezes the evaluator's DDS threads as well. Over shared memory a frozen reader's full port
    # holds up every writer to it (Fast DDS waits out a health check of the port per message), so the
    # separator would stall too; over UDP the frozen reader only loses datagrams and the stall stays its
    # own, as when a node is busy in a callback.
    procs = start_graph(processes, small_data_dir, tmp_path, udp_only=("evaluator_node",),
                        sim=dict(num_episodes=30, step_timeout_s=10.0, max_evaluator_lag=lag))
    deadline = time.monotonic() + 120
    while not (tmp_path / "scores" / "results.json").exists():  # the first episode is scored
        if procs["sim_node"].poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"the run never got going: {procs['sim_node'].communicate()[1]}")
        time.sleep(0.1)
    procs["evaluator_node"].send_signal(signal.SIGSTOP)  # alive (in the graph) but scoring nothing
    try:
        _, err = procs["sim_node"].communicate(timeout=60)
    finally:
        procs["evaluator_node"].send_signal(signal.SIGCONT)
    assert procs["sim_node"].returncode == 2
    unscored = re.search(r"evaluator_node left (\d+) observations unscored", err)
    assert unscored, err
    assert 1 <= int(unscored.group(1)) <= lag


def test_bad_params_file_names_the_parameter(processes, tmp_path):
    params = tmp_path / "sim.yaml"
    params.write_text("sim_node:\n  ros__parameters:\n    mic_noise: -1.0\n")
    proc = processes.start(node_args("sim_node")[:-2] + ["--params-file", str(params)])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert "mic_noise" in err


def test_nan_audio_stops_the_separator_with_the_reason(processes, small_data_dir, tmp_path):
    separator = processes.start(node_args("separator_node", target_class="speech"), env=node_env(small_data_dir))
    probe = processes.start(["python", "-c", PUBLISH_NAN_AUDIO], env=node_env(small_data_dir))
    _, err = separator.communicate(timeout=60)
    processes.interrupt(probe)
    assert separator.returncode == 2
    assert "AudioError" in err and "NaN" in err


def test_wrong_shape_audio_stops_the_separator_with_the_reason(processes, small_data_dir):
    separator = processes.start(node_args("separator_node", target_class="speech"), env=node_env(small_data_dir))
    probe = processes.start(["python", "-c", PUBLISH_NAN_AUDIO.replace("np.nan", "0.1").replace("(2, 16000)", "(2, 8000)")],
                            env=node_env(small_data_dir))
    _, err = separator.communicate(timeout=60)
    processes.interrupt(probe)
    assert separator.returncode == 2
    assert "AudioError" in err and "16000 values, expected 32000" in err


PUBLISH_NAN_AUDIO = """
import time, numpy as np, rclpy
from m2h_msgs.msg import BinauralAudio
from m2h_ros.ros import convert
from m2h_ros.ros.qos import STEP
rclpy.init()
node = rclpy.create_node("bad_audio_probe")
pub = node.create_publisher(BinauralAudio, "audio", STEP)
samples = np.full((2, 16000), np.nan, np.float32)
while pub.get_subscription_count() == 0:
    rclpy.spin_once(node, timeout_sec=0.1)
time.sleep(0.5)
pub.publish(convert.audio_msg(samples, sample_rate=16000, episode_id="probe", step=0, stamp_ns=1))
rclpy.spin(node)
"""


def test_free_running_counts_dropped_steps(small_library, small_data_dir, tmp_path):
    """At a rate the graph cannot follow, missed steps hold the robot, are counted, and still score."""
    result = run_pipeline(tmp_path, small_data_dir, "--episodes", "1", "--mode", "free_running", "--rate", "200",
                          "--controller", CONTROLLER, *tiny_sets())
    assert result.returncode == 0, result.stdout + result.stderr
    sim_log = (tmp_path / "logs" / "sim_node.log").read_text()
    dropped = int(re.search(r"(\d+) dropped \(held\)", sim_log).group(1))
    episode = read_results(tmp_path / "scores" / "results.json")[0]
    assert len(episode.si_sdr) == episode.steps + 1 == 21
    assert 0 < dropped == episode.actions.count(-1)


def test_replayed_bag_scores_equal_the_live_ones(tiny_run):
    """m2h-eval's core on the recorded bag: the evaluator's results exactly (same code, same data), also
    with the batches scored by two other processes."""
    from m2h_ros.io.replay import ReplayConfig, replay_bag

    out, _ = tiny_run
    live = read_results(out / "scores" / "results.json")
    for config in (ReplayConfig(), ReplayConfig(score_processes=2)):
        replay = replay_bag(out / "bag", config=config)
        assert replay.problems == [] and replay.comparison.mismatches == [], \
            [str(p) for p in replay.problems] + [str(m) for m in replay.comparison.mismatches]
        assert [r.to_dict() for r in replay.results] == [r.to_dict() for r in live], \
            (replay.results, live)
        assert replay.comparison.steps == sum(len(r.si_sdr) for r in live) and replay.comparison.episodes == 2
        assert set(replay.comparison.max_diff.values()) == {0.0}, replay.comparison.max_diff


def test_play_binaural_separates_a_file_through_the_live_separator(processes, small_data_dir, speech_under_music,
                                                                 tmp_path):
    """A stereo file as a live microphone (no simulator): every 1 s frame comes back separated, and the
    target comes out clearer than in the mixture (by the floor m2h-separate is held to: same model)."""
    import scipy.signal
    import soundfile

    from m2h_ros.core.audio.metrics import si_sdr

    mixture, reference = speech_under_music
    rate = 22050
    soundfile.write(tmp_path / "in.wav", scipy.signal.resample_poly(mixture, 441, 320, axis=0), rate, subtype="FLOAT")
    separator = processes.start(node_args("separator_node", target_class="speech"), env=node_env(small_data_dir))
    player = processes.start(["python", str(ROOT / "scripts" / "play_binaural.py"), str(tmp_path / "in.wav"),
                              "--listen", str(tmp_path / "out.wav"), "--speed", "20"], env=node_env(small_data_dir))
    out, err = player.communicate(timeout=90)
    processes.interrupt(separator)
    assert player.returncode == 0, err
    assert "3 frames separated" in out
    separated, out_rate = soundfile.read(tmp_path / "out.wav")
    # the default listener output: both ears, scored as their mean
    assert out_rate == rate and separated.shape == (len(mixture) * 441 // 320, 2)
    estimate = scipy.signal.resample_poly(separated.mean(axis=1), 320, 441)[: len(reference)]
    gain = si_sdr(estimate, reference) - si_sdr(mixture.mean(axis=1), reference)
    assert gain > SEPARATION_FLOOR_DB, f"{gain:+.2f} dB over the mixture"


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_run_pipeline_stopped_or_killed_leaves_no_node_running(signum, small_library, small_data_dir, tmp_path):
    """SIGTERM stops every node in order, as Ctrl-C does; SIGKILL, which the script cannot catch, still
    stops them (each node's parent-death signal)."""
    marker = f"stopped-{os.getpid()}-{time.monotonic_ns()}"
    env = {**node_env(small_data_dir), "M2H_TEST_MARKER": marker}
    run = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--out", str(tmp_path),
                            "--episodes", "30", "--controller", CONTROLLER, *tiny_sets()],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
                           start_new_session=True)

    def marked_nodes() -> list[int]:
        pids = []
        for proc in Path("/proc").iterdir():
            try:
                if proc.name.isdigit() and marker.encode() in (proc / "environ").read_bytes():
                    pids.append(int(proc.name))
            except OSError:
                pass
        return [pid for pid in pids if pid != run.pid]

    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "scores" / "results.json").exists():  # the run is under way
            assert run.poll() is None and time.monotonic() < deadline, run.communicate()
            time.sleep(0.1)
        assert marked_nodes()
        run.send_signal(signum)
        out, _ = run.communicate(timeout=60)
        if signum == signal.SIGTERM:
            assert "interrupted: stopping every node" in out
            assert run.returncode == 130, out
            assert not marked_nodes()
        deadline = time.monotonic() + 30
        while left := marked_nodes():
            if time.monotonic() > deadline:
                names = [Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[1].decode() for pid in left]
                logs = {log.name: log.read_text()[-1500:] for log in (tmp_path / "logs").iterdir()}
                pytest.fail(f"still running 30 s after run_pipeline's {signum.name}: {names}; logs {logs}")
            time.sleep(0.2)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
        for pid in marked_nodes():
            os.kill(pid, signal.SIGKILL)


def _layout_panels(node):
    if node.get("type") == "panel":
        yield node
    for item in node.get("items", []):
        yield from _layout_panels(item["content"])


def test_every_panel_of_the_foxglove_layout_shows_what_the_run_recorded(tiny_run):
    """params/foxglove_layout.json against a recorded run: each panel's topic is in the bag with the kind of
    message the panel draws, each plotted field exists and is a number, the 3D view follows a frame of
    the bag's TF tree, and the spectrogram colour scale spans most of the recorded pictures' values."""
    import json

    out, _ = tiny_run
    messages = bag_messages(out / "bag")
    panels = list(_layout_panels(json.loads((ROOT / "params" / "foxglove_layout.json").read_text())["content"]))
    assert {p["panelType"] for p in panels} == {"ThreeDee", "Image", "Plot", "Audio"}
    frames = {t.child_frame_id for m in messages["/tf"] + messages["/tf_static"] for t in m.transforms}
    for panel in panels:
        config = panel["config"]
        if panel["panelType"] == "ThreeDee":
            assert config["followTf"] in frames
            for topic in config["topics"]:
                assert messages.get(topic), topic
            assert hasattr(messages["/map"][0], "info") and hasattr(messages["/path"][0], "markers")
        elif panel["panelType"] == "Plot":
            for series in config["paths"]:
                topic, field = series["value"].split(".")
                assert messages.get(topic) and all(np.isfinite(float(getattr(m, field))) for m in messages[topic])
        elif panel["panelType"] == "Audio":
            assert all(m.format == "pcm-s16" and len(m.data) for m in messages[config["topic"]]), config["topic"]
        else:
            mode = config["imageMode"]
            images = messages.get(mode["imageTopic"], [])
            assert images and all(len(m.data) == m.height * m.step for m in images), mode["imageTopic"]
            if "calibrationTopic" in mode:
                (info, *_) = messages[mode["calibrationTopic"]]
                assert (info.width, info.height) == (images[0].width, images[0].height)
            if "minValue" in mode:
                values = np.concatenate([np.frombuffer(bytes(m.data), "<f4") for m in images])
                shown = (values >= mode["minValue"]) & (values <= mode["maxValue"])
                assert shown.mean() > 0.5, (mode["imageTopic"], np.percentile(values, [5, 50, 95]))


def _stamp(msg) -> int:
    header = msg.markers[0].header if hasattr(msg, "markers") else msg.header  # a MarkerArray has none itself
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def _latest(entries: list, stamp: int):
    """The message of ``entries`` (log_time, type, message) stamped last at or before ``stamp``: the
    episode's (each episode's map and markers carry its first step's stamp; the bag's log order may
    interleave two episodes, since the simulator runs ahead of the evaluator)."""
    return max((m for _, _, m in entries if _stamp(m) <= stamp), key=_stamp)


def _cell(grid, x: float, y: float) -> int:
    """The occupancy of the map cell under (x, y) in the map frame (the grid's origin pose, row-major rows
    of increasing y): -1 unknown, 0 free, 100 occupied; AssertionError outside the grid."""
    origin = grid.info.origin
    yaw = 2 * np.arctan2(origin.orientation.z, origin.orientation.w)
    dx, dy = x - origin.position.x, y - origin.position.y
    gx, gy = np.cos(yaw) * dx + np.sin(yaw) * dy, -np.sin(yaw) * dx + np.cos(yaw) * dy
    col, row = int(np.floor(gx / grid.info.resolution)), int(np.floor(gy / grid.info.resolution))
    assert 0 <= col < grid.info.width and 0 <= row < grid.info.height, (x, y, col, row)
    return int(np.int8(grid.data[row * grid.info.width + col]))


def check_map_and_markers(decoded: dict) -> None:
    """The map is the floor plan the robot walks: every pose of the robot and every source lies on a free
    cell of it (a transposed grid, a wrong origin or resolution puts some in a wall or off the grid); the
    target's marker is where the ground truth's distances say (never farther in a straight line than
    along the grid, and where the robot stands when it is at the target); the path marker is the poses."""
    for _, _, grid in decoded["/map"]:
        cells = np.array(grid.data, np.int8)
        assert grid.info.width * grid.info.height == cells.size and {0, 100} <= set(np.unique(cells)) <= {-1, 0, 100}
    truth = {(m.episode_id, m.step): m for _, _, m in decoded[topics.GROUND_TRUTH]}
    at_target = 0
    for _, _, pose in decoded["/agent_pose"]:
        grid, markers = _latest(decoded["/map"], _stamp(pose)), _latest(decoded[topics.SOURCES], _stamp(pose)).markers
        assert markers[0].action == 3 and [m.type for m in markers if m.ns == "sources"] == [2, 2]  # DELETEALL; 2 spheres
        x, y = pose.pose.position.x, pose.pose.position.y
        assert _cell(grid, x, y) == 0, f"robot at ({x}, {y}) on a cell that is not free"
        spheres = [m.pose.position for m in markers if m.ns == "sources"]
        for sphere in spheres:
            assert _cell(grid, sphere.x, sphere.y) == 0, f"source at ({sphere.x}, {sphere.y}) on a cell that is not free"
        straight = np.hypot(spheres[0].x - x, spheres[0].y - y)
        step = truth[(pose.episode_id, pose.step)]
        assert straight <= step.geodesic_distance + 1e-6
        if step.at_target:
            at_target += 1
            assert straight < 1e-6
    path = decoded["/path"][-1][2].markers[0].points
    last = [m for _, _, m in decoded["/agent_pose"] if m.episode_id == decoded["/agent_pose"][-1][2].episode_id]
    assert [(p.x, p.y) for p in path] == [(m.pose.position.x, m.pose.position.y) for m in last]


def check_spectrogram_pictures(decoded: dict) -> None:
    """Each step's pictures are the spectrograms they name: the mixture's is the picture of the recorded
    audio's STFT, the refined estimate's the picture of the separator's refined output (an all-zero, a
    constant or a stale picture fails)."""
    from m2h_ros.core.audio.display import spectrogram_image
    from m2h_ros.core.audio.stft import stft

    def picture(image) -> np.ndarray:
        assert (image.encoding, image.height, image.width) == ("32FC1", 128, 32)
        return np.frombuffer(bytes(image.data), "<f4").reshape(image.height, image.width)

    audio = {(m.header.stamp.sec, m.header.stamp.nanosec): m for _, _, m in decoded["/audio"]}
    refined = {(m.header.stamp.sec, m.header.stamp.nanosec): m for _, _, m in decoded["/separator/refined"]}
    pictures = {topic: [m for _, _, m in decoded["/" + topic]] for topic in (topics.MIXTURE_IMAGE, topics.REFINED_IMAGE)}
    assert len(pictures[topics.MIXTURE_IMAGE]) == len(audio) and len(pictures[topics.REFINED_IMAGE]) == len(refined)
    for image in pictures[topics.MIXTURE_IMAGE]:
        sound = audio[(image.header.stamp.sec, image.header.stamp.nanosec)]
        samples = np.asarray(sound.samples, np.float32).reshape(sound.channels, -1)
        np.testing.assert_allclose(picture(image), spectrogram_image(np.abs(stft(samples))), atol=1e-3)
    for image in pictures[topics.REFINED_IMAGE]:
        estimate = refined[(image.header.stamp.sec, image.header.stamp.nanosec)]
        magnitude = np.asarray(estimate.data, np.float32).reshape(tuple(estimate.shape))
        np.testing.assert_allclose(picture(image), spectrogram_image(magnitude), atol=1e-3)
    for topic in pictures:
        assert np.ptp(picture(pictures[topic][0])) > 10  # dB of contrast: something to see


def test_the_bag_shows_the_run_in_foxglove_and_rviz(tiny_run):
    """Read with the independent reader (`mcap` + `mcap-ros2-support`, as Foxglove's tools decode ROS 2
    bags): every message decodes; the TF tree joins map to the camera; the map, markers and spectrogram
    pictures are well formed; the RawAudio tracks are pcm-s16 holding the recorded audio; the timeline
    starts with the run, not with the nodes' start-up log lines."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from m2h_ros.io.derived import PCM_GAIN

    out, _ = tiny_run
    decoded: dict[str, list] = {}
    with next((out / "bag").glob("*.mcap")).open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages():
            decoded.setdefault(channel.topic, []).append((message.log_time, schema.name, msg))
    types = {topic: entries[0][1] for topic, entries in decoded.items()}
    expected = {"/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage",
                "/map": "nav_msgs/msg/OccupancyGrid", "/path": "visualization_msgs/msg/MarkerArray",
                topics.SOURCES: "visualization_msgs/msg/MarkerArray", topics.TARGET_IMAGE: "sensor_msgs/msg/Image",
                "/audio/pcm": "foxglove_msgs/msg/RawAudio", "/separator/audio/pcm": "foxglove_msgs/msg/RawAudio",
                "/ground_truth/target/pcm": "foxglove_msgs/msg/RawAudio",
                **{"/" + t: "sensor_msgs/msg/Image" for t in (topics.MIXTURE_IMAGE, topics.BINAURAL_IMAGE,
                                                               topics.MONAURAL_IMAGE, topics.REFINED_IMAGE)}}
    assert {t: types.get(t) for t in expected} == expected

    # TF: map -> odom -> base_link -> head -> camera, static parts once, odom -> base_link per step.
    (static,) = [m for _, _, m in decoded["/tf_static"]]
    parents = {t.child_frame_id: t.header.frame_id for t in static.transforms}
    for _, _, m in decoded["/tf"]:
        parents.update({t.child_frame_id: t.header.frame_id for t in m.transforms})
    chain, frame = ["camera"], "camera"
    while frame in parents:
        frame = parents[frame]
        chain.append(frame)
    assert chain == ["camera", "head", "base_link", "odom", "map"]
    head = next(t for t in static.transforms if t.child_frame_id == "head").transform.translation
    assert head.z == pytest.approx(1.5)
    odoms = [m for _, _, m in decoded["/odom"]]
    assert len(decoded["/tf"]) == len(odoms)
    for (_, _, tf), odom in zip(decoded["/tf"], odoms, strict=True):
        (t,) = tf.transforms
        assert (t.header.stamp.sec, t.header.stamp.nanosec) == (odom.header.stamp.sec, odom.header.stamp.nanosec)
        assert (t.transform.translation.x, t.transform.translation.y) == (odom.pose.pose.position.x,
                                                                          odom.pose.pose.position.y)
    # Odometry's twist is the motion to this observation: over the time between the two stamps it covers
    # the step (1 m forward or a quarter turn); the first observation of an episode stands still.
    poses = [m for _, _, m in decoded["/agent_pose"]]
    moved = 0
    for previous, (pose, odom) in zip(poses, zip(poses[1:], odoms[1:], strict=True)):
        if pose.episode_id != previous.episode_id:
            assert odom.twist.twist.linear.x == odom.twist.twist.angular.z == 0.0
            continue
        seconds = (pose.header.stamp.sec - previous.header.stamp.sec) + (
            pose.header.stamp.nanosec - previous.header.stamp.nanosec) / 1e9
        distance = np.hypot(pose.pose.position.x - previous.pose.position.x, pose.pose.position.y - previous.pose.position.y)
        assert odom.twist.twist.linear.x * seconds == pytest.approx(distance, abs=1e-6)
        moved += distance > 0 or odom.twist.twist.angular.z != 0
    assert moved > 0

    check_map_and_markers(decoded)
    check_spectrogram_pictures(decoded)

    # RawAudio: pcm-s16 of exactly the recorded samples (to 16-bit resolution where not clipped).
    for pcm_topic, source, field, channels in (("/audio/pcm", "/audio", "samples", 2),
                                               ("/separator/audio/pcm", "/separator/audio", "samples", 2),
                                               ("/ground_truth/target/pcm", topics.GROUND_TRUTH, "target_monaural", 1)):
        pcm = [m for _, _, m in decoded[pcm_topic]]
        assert len(pcm) == len(decoded[source])
        for audio, (_, _, original) in zip(pcm, decoded[source], strict=True):
            assert (audio.format, audio.sample_rate, audio.number_of_channels) == ("pcm-s16", 16000, channels)
            assert (audio.timestamp.sec, audio.timestamp.nanosec) == (original.header.stamp.sec,
                                                                       original.header.stamp.nanosec)
            samples = np.asarray(getattr(original, field), np.float32).reshape(channels, -1)
            heard = np.frombuffer(bytes(audio.data), "<i2").reshape(-1, channels).T / (32767 * PCM_GAIN)
            clipped = np.abs(samples) * PCM_GAIN >= 1
            assert heard.shape == samples.shape and not clipped.all()
            np.testing.assert_allclose(heard[~clipped], samples[~clipped], atol=1 / (32767 * PCM_GAIN))

    first_data = min(t for topic, entries in decoded.items() if topic != "/rosout" for t, _, _ in entries)
    assert min(t for t, _, _ in decoded["/rosout"]) >= first_data
    assert first_data >= decoded["/episode"][0][0] - 0.5e9
