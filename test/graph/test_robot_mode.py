"""Robot mode end to end (scripts/run_pipeline.py --robot): a virtual microphone through the real ALSA
stack and capture_node, or an audio_common stream through audio_common_adapter; the episode driver, the
separator, the shipped Move2Hear controller with a test camera's RGB-D, base_node on the test-only
kinematic base, and the recorder; no simulator, no evaluator. Without a camera, a controller that reads
images is refused naming why."""

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pipeline_helpers import ROOT, bag_messages

from m2h_ros.io.virtual_mic import virtual_mic

pytestmark = pytest.mark.graph
RATE = 48000
HERE = Path(__file__).parent
STEPS = 2
NODES = ("episode_driver", "separator_node", "controller_node", "base_node", "recorder_node")
# From Ctrl-C to the base's zero velocity: its own shutdown, not the other nodes' (seconds each, loaded).
STOPS_THE_BASE_WITHIN_S = 1.5


def robot_run(tmp_path, *args: str, env: dict | None = None, timeout: float = 300):
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", **(env or {})}  # no data: robot mode simulates nothing
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--robot", "--out",
                           str(tmp_path / "run"), "--steps", str(STEPS), *args],
                          capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)


def tone_microphone(tmp_path):
    """A virtual microphone playing two tones and noise, longer than any run: it never falls silent."""
    rng = np.random.default_rng(3)
    t = np.arange(RATE * 120) / RATE
    ears = np.stack([np.sin(2 * np.pi * 220 * t) * (1 + 0.5 * np.sin(2 * np.pi * 3 * t)),
                     np.sin(2 * np.pi * 330 * t)], axis=1) * 0.2 + 0.05 * rng.standard_normal((t.size, 2))
    return virtual_mic(tmp_path / "mic", ears.astype(np.float32), RATE)


def mic_run(tmp_path, *args: str, timeout: float = 300):
    """Robot mode with capture_node on a virtual microphone."""
    mic = tone_microphone(tmp_path)
    return robot_run(tmp_path, "--device", mic.name, "--set", f"capture_node.sample_rate={RATE}", *args,
                     env=mic.env(), timeout=timeout)


def check_episode(result, tmp_path, microphones: str) -> dict:
    """The run's episode: every node exited 0, steps 0..STEPS each answered by Move2Hear and carried
    out by the base, each later step captured after the move before it ended. Returns the bag's messages."""
    assert result.returncode == 0, result.stdout + result.stderr
    for node in (microphones, *NODES):
        assert f"[run]   {node:16s} exit 0" in result.stdout
    messages = bag_messages(tmp_path / "run" / "bag")
    assert "/ground_truth/target" not in messages and "/scores/step" not in messages  # no sim, no evaluator
    # Robot mode's bag leaves out the raw camera streams (each step's images are kept) and compresses its chunks.
    assert "/camera/rgb/image_raw" not in messages and "/camera/depth/image_raw" not in messages
    from mcap.reader import make_reader

    (mcap,) = (tmp_path / "run" / "bag").glob("*.mcap")
    with mcap.open("rb") as stream:
        assert {chunk.compression for chunk in make_reader(stream).get_summary().chunk_indexes} == {"zstd"}
    steps = [(m.episode_id, m.step) for m in messages["/audio"]]
    assert steps == [("robot", k) for k in range(STEPS + 1)]
    commands = messages["/cmd"]
    assert [c.step for c in commands] == list(range(STEPS)) and {c.controller for c in commands} == {"move2hear"}
    results = messages["/motion_result"]
    assert [(r.step, r.status) for r in results] == [(k, 0) for k in range(STEPS)]  # DONE
    assert [r.action for r in results] == [c.action for c in commands]
    # Each step after the first is a frame captured wholly after the move before it ended.
    stamp = lambda m: m.header.stamp.sec * 10**9 + m.header.stamp.nanosec  # noqa: E731
    for k in range(1, STEPS + 1):
        assert stamp(messages["/audio"][k]) >= stamp(results[k - 1])
    assert len(messages["/mic/audio"]) > STEPS + 1  # the stream went on between steps
    assert len(messages["/separator/audio"]) == STEPS + 1
    assert [m.header.stamp for m in messages["/step/odom"]] == [m.header.stamp for m in messages["/audio"]]
    return messages


def test_the_robot_graph_runs_an_episode_with_move2hear_on_the_test_base(processes, tmp_path):
    processes.start([sys.executable, str(HERE / "kinematic_base.py")])
    processes.start([sys.executable, str(HERE / "camera_publisher.py")])
    check_episode(mic_run(tmp_path), tmp_path, "capture_node")


def test_a_driver_with_its_own_topic_names_runs_the_same_episode(processes, tmp_path):
    """A base on /wheel/odometry and /base/cmd_vel and a camera on /head/...: remapped, not patched; the
    driver's raw camera streams stay out of the bag under their own names."""
    names = {"odom": "/wheel/odometry", "cmd-vel": "/base/cmd_vel", "rgb": "/head/color", "depth": "/head/depth"}
    processes.start([sys.executable, str(HERE / "kinematic_base.py"), "--ros-args",
                     "-r", f"odom:={names['odom']}", "-r", f"cmd_vel:={names['cmd-vel']}"])
    processes.start([sys.executable, str(HERE / "camera_publisher.py"), "--ros-args",
                     "-r", f"camera/rgb/image_raw:={names['rgb']}", "-r", f"camera/depth/image_raw:={names['depth']}"])
    options = [item for key, name in names.items() for item in (f"--{key}-topic", name)]
    messages = check_episode(mic_run(tmp_path, *options), tmp_path, "capture_node")
    assert "/head/color" not in messages and "/head/depth" not in messages  # the raw streams, left out
    assert "/odom" not in messages and "/cmd_vel" not in messages  # nothing on the pipeline's own names
    assert "/wheel/odometry" in messages and "/base/cmd_vel" in messages
    assert len(messages["/step/camera/rgb/image_raw"]) == STEPS + 1
    # After the run (docs/how-to/robot-mode.md): the video shows and plays it; the floor-plan view and the
    # scoring name what a robot's bag lacks instead of failing with a traceback.
    bag = tmp_path / "run" / "bag"
    video = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_video.py"), str(bag), "--out",
                            str(tmp_path / "run.mp4")], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert video.returncode == 0 and "audio stream 1 the mixture, stream 2 the separated estimate" in video.stdout
    view = subprocess.run([sys.executable, str(ROOT / "scripts" / "view_bag.py"), str(bag), "--out",
                           str(tmp_path / "view.png")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert view.returncode == 2 and "no /map, so no floor plan to draw" in view.stderr, view.stderr
    scored = subprocess.run([str(ROOT / "scripts" / "bin" / "m2h-eval"), str(bag), "--out", str(tmp_path / "eval")],
                            capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert scored.returncode == 3 and "no usable message on /ground_truth/target" in scored.stdout + scored.stderr


def test_an_audio_common_stream_and_a_driver_sized_camera_run_the_same_episode(processes, tmp_path):
    """ros-drivers' audio_capture as its capture_wave launch file runs it, and a RealSense-style camera:
    640 x 480 bgr8 colour, 16UC1 millimetre depth (the controller fits both to its 128 x 128 images)."""
    processes.start([sys.executable, str(HERE / "kinematic_base.py")])
    processes.start([sys.executable, str(HERE / "camera_publisher.py"), "--width", "640", "--height", "480",
                     "--driver"])
    processes.start([sys.executable, str(HERE / "audio_capture_stand_in.py"), "--rate", str(RATE)])
    messages = check_episode(robot_run(tmp_path, "--microphones", "audio_common"), tmp_path, "audio_common_adapter")
    assert "/audio/audio_stamped" in messages and "/audio/audio_info" in messages  # the driver's stream, recorded
    # The controller answered every step from the driver's images as they came
    rgb, depth = messages["/step/camera/rgb/image_raw"], messages["/step/camera/depth/image_raw"]
    assert {(m.encoding, m.width, m.height) for m in rgb} == {("bgr8", 640, 480)} and len(rgb) == STEPS + 1
    assert {(m.encoding, m.width, m.height) for m in depth} == {("16UC1", 640, 480)} and len(depth) == STEPS + 1


def test_without_a_camera_a_controller_that_reads_images_is_refused(tmp_path):
    result = mic_run(tmp_path, "--no-camera", timeout=180)
    assert result.returncode == 1
    assert "controller_node exited during the run" in result.stdout
    assert "controller 'move2hear' reads camera images and camera is false" in result.stdout


def test_without_odometry_or_camera_the_run_ends_within_its_timeout_naming_them(tmp_path):
    """No base driver and no camera: the episode driver stops after input_timeout_s, naming each input
    that never came, instead of waiting for them for ever."""
    started = time.monotonic()
    result = mic_run(tmp_path, "--set", "episode_driver.input_timeout_s=5", timeout=180)
    assert result.returncode == 1, result.stdout + result.stderr
    assert f"[run]   {'episode_driver':16s} exit 2" in result.stdout, result.stdout
    assert ("step 0: no odometry on /odom; no camera images on /camera/rgb/image_raw, /camera/depth/image_raw "
            "within 5 s (input_timeout_s)") in result.stdout
    assert "microphone frames" not in result.stdout  # the microphone worked
    assert time.monotonic() - started < 120


def test_without_any_robot_input_the_run_ends_naming_the_microphone_too(tmp_path):
    """An audio_common stream that never comes (no driver), no base, no camera."""
    result = robot_run(tmp_path, "--microphones", "audio_common", "--set", "episode_driver.input_timeout_s=5",
                       timeout=180)
    assert result.returncode == 1, result.stdout + result.stderr
    assert ("step 0: no microphone frames on /mic/audio; no odometry on /odom; no camera images on "
            "/camera/rgb/image_raw, /camera/depth/image_raw within 5 s (input_timeout_s)") in result.stdout


def test_an_interrupted_run_stops_the_base_first(processes, tmp_path):
    """Ctrl-C (SIGINT to run_pipeline.py; SIGTERM does the same) during a move: base_node stops before any
    other node, so the robot gets zero velocity at once, not after the episode driver, the controller and
    the separator have shut down. The base is slowed so that every move outlasts the test."""
    processes.start([sys.executable, str(HERE / "kinematic_base.py")])
    processes.start([sys.executable, str(HERE / "camera_publisher.py")])
    mic = tone_microphone(tmp_path)
    slow = [item for setting in ("max_linear_speed=0.01", "max_angular_speed=0.01", "move_timeout_s=600")
            for item in ("--set", f"base_node.{setting}")]
    run = processes.start([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--robot", "--out",
                           str(tmp_path / "run"), "--steps", "20", "--device", mic.name, "--set",
                           f"capture_node.sample_rate={RATE}", *slow],
                          env={**os.environ, "OMP_WAIT_POLICY": "PASSIVE", **mic.env()})
    base_log = tmp_path / "run" / "logs" / "base_node.log"
    deadline = time.monotonic() + 240
    # The first command under way: the base's command velocity is on the bag's topic list by then.
    driver_log = tmp_path / "run" / "logs" / "episode_driver.log"
    while not (driver_log.exists() and "step 0 out" in driver_log.read_text()):
        assert run.poll() is None and time.monotonic() < deadline, "the robot run did not reach step 0"
        time.sleep(0.2)
    time.sleep(8.0)  # the controller's first command is out and the base is moving (a move takes over 60 s)
    interrupted = time.time()
    code, out, err = processes.interrupt(run, timeout=120)
    assert code == 130, out + err  # 128 + SIGINT
    messages = bag_messages(tmp_path / "run" / "bag")
    (result,) = messages["/motion_result"]
    assert (result.step, result.status, result.reason) == (0, 2, "base_node shut down"), result  # ABORTED
    velocity = messages["/cmd_vel"]
    assert any(abs(v.twist.linear.x) + abs(v.twist.angular.z) > 0 for v in velocity)  # it was moving
    assert velocity[-1].twist.linear.x == velocity[-1].twist.angular.z == 0.0
    stopped = result.header.stamp.sec + result.header.stamp.nanosec * 1e-9
    print(f"zero velocity {stopped - interrupted:.2f} s after the interrupt")
    assert stopped - interrupted < STOPS_THE_BASE_WITHIN_S, base_log.read_text()[-2000:]
