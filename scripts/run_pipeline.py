#!/usr/bin/env python3
"""Run the whole pipeline as five ROS 2 processes: sim, separator, controller, evaluator, recorder.

    python scripts/run_pipeline.py --episodes 3 --controller doa --out runs/demo
    python scripts/run_pipeline.py --set sim_node.mic_noise=0.1 --set controller_node.seed=3
    python scripts/run_pipeline.py --live-view      # and open ws://localhost:8765 in Foxglove
    python scripts/run_pipeline.py --robot --target-class speech --steps 20 --device ReSpeaker
    python scripts/run_pipeline.py --robot --odom-topic /wheel/odometry --cmd-vel-topic /base/cmd_vel

--robot runs the pipeline on a robot instead (docs/how-to/robot-mode.md): capture_node, episode_driver,
separator, controller, base_node and recorder; no simulator, no evaluator; the episode driver ends it.

Builds the data the episodes need first (sound library, episode file; RIR banks of the sources are
built by the simulator on first use), starts every node with its params file from params/ (plus the
overrides), waits for the simulator to finish its episodes, then stops the other nodes in order
(SIGINT, wait, SIGKILL if one hangs) and prints the scores table and where the bag, the tables and the
plot are. The recorder leaves out what is derived from other topics (spectrogram pictures, pcm-s16
tracks, the path, TF), so no node builds it during the run; once the recorder has closed the bag, the
same topics are added to it from the raw ones (m2h-derive), unless --set recorder_node.keep_derived=true
recorded them live. Exit code 0 only if every node exited cleanly. Node logs go to OUT/logs/. Should this
script itself be killed (SIGKILL, an out-of-memory kill), every node gets SIGTERM and stops: none outlives it.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import yaml

from m2h_ros.core.world.worlds import canonical_spec
from m2h_ros.errors import BagError, M2HError
from m2h_ros.io.derive_bag import derive_bag
from m2h_ros.io.topic_selection import COMPRESSIONS
from m2h_ros.node_configs import (DRIVER_TOPICS, MICROPHONES, NODE_CONFIGS, ROBOT_CONFIGS, robot_recording,
                                  robot_remaps)
from m2h_ros.ros import stop_signals

ROOT = Path(__file__).resolve().parents[1]
# Start order: the live view and the recorder first, so they hear every topic from its first message.
NODES = tuple(NODE_CONFIGS)
# Stop order: the recorder and the live view last, so they keep every message the others sent.
STOP_ORDER = ("controller_node", "separator_node", "evaluator_node", "base_node", "capture_node",
              "audio_common_adapter", "recorder_node", "live_view_node")
LIVE_VIEW_PORT = 8765  # Foxglove's default
STOP_TIMEOUT_S = 20.0


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--episodes", type=int, default=3, help="episodes to play (default 3)")
    parser.add_argument("--first", type=int, default=0, help="index of the first test episode")
    parser.add_argument("--task", default="near_target", choices=("near_target", "far_target"))
    parser.add_argument("--sound-split", default="unheard", choices=("heard", "unheard"))
    parser.add_argument("--world", default="", metavar="SPEC",
                        help="the world: map:PATH/map.yaml (a nav2 map), mesh:PATH (glb, gltf, obj, ply); "
                             "default: the generated test scenes")
    parser.add_argument("--controller", default=None, help="controller_node policy (default: its params file)")
    parser.add_argument("--separator-checkpoint", default=None, help="separator .pt (default: the shipped one)")
    parser.add_argument("--mode", default="lockstep", choices=("lockstep", "free_running"))
    parser.add_argument("--rate", type=float, default=None, help="free_running steps per second")
    parser.add_argument("--step-timeout", type=float, default=30.0, help="seconds a node may take per step")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.PARAM=VALUE",
                        help="override any node parameter (repeatable)")
    parser.add_argument("--out", type=Path, default=None, help="run directory (default runs/<date-time>)")
    parser.add_argument("--no-record", action="store_true", help="run without the recorder")
    parser.add_argument("--live-view", type=int, nargs="?", const=LIVE_VIEW_PORT, default=None, metavar="PORT",
                        help=f"also serve the run to Foxglove on ws://127.0.0.1:PORT (default {LIVE_VIEW_PORT}), "
                             "from the recorder's process unless --no-record; other live_view_node settings "
                             "with --set")
    recording = parser.add_argument_group("what the bag keeps (default: everything; in robot mode all but the raw "
                                          "camera streams, zstd-compressed)")
    recording.add_argument("--record-topics", nargs="+", default=None, metavar="TOPIC",
                           help="record only these topics (names or shell-style patterns: '/camera/*')")
    recording.add_argument("--record-exclude", nargs="*", default=None, metavar="TOPIC",
                           help="never record these (names or patterns); with none given, leave nothing out")
    recording.add_argument("--record-max-rate", action="append", default=None, metavar="TOPIC=HZ",
                           help="record at most HZ messages per second of TOPIC (repeatable)")
    recording.add_argument("--compression", choices=COMPRESSIONS, default=None,
                           help="MCAP chunk compression (default: none; zstd in robot mode)")
    robot = parser.add_argument_group("robot mode")
    robot.add_argument("--robot", action="store_true", help="run on a robot: microphones, base, no simulator")
    robot.add_argument("--target-class", default="speech", choices=("speech", "music"))
    robot.add_argument("--steps", type=int, default=20, help="actions in the robot's episode (default 20)")
    robot.add_argument("--microphones", default="capture", choices=tuple(MICROPHONES),
                       help="capture: a microphone PortAudio sees (capture_node); audio_common: the robot's "
                            "audio_common stream (audio_common_adapter)")
    robot.add_argument("--device", default=None, help="capture_node device (default: its params file)")
    robot.add_argument("--no-camera", action="store_true",
                       help="the robot passes no RGB-D: only controllers that read no images run")
    for key, (topic, _, what) in DRIVER_TOPICS.items():
        robot.add_argument(f"--{key.replace('_', '-')}-topic", dest=f"{key}_topic", default=topic, metavar="TOPIC",
                           help=f"{what} as the robot's driver names it (default: {topic})")
    return parser.parse_args(argv)


def robot_overrides(args: argparse.Namespace) -> dict[str, dict[str, object]]:
    """Robot mode's parameter values per node (on top of each node's params file)."""
    params: dict[str, dict[str, object]] = {node: {} for node in ROBOT_CONFIGS}
    camera = not args.no_camera
    params["episode_driver"].update(target_class=args.target_class, steps=args.steps, task=args.task, camera=camera)
    params["separator_node"]["target_class"] = args.target_class
    params["controller_node"]["camera"] = camera
    if args.device is not None:
        params["capture_node"]["device"] = args.device
    return params


def driver_topics(args: argparse.Namespace) -> dict[str, str]:
    """The robot driver's topic names this run was given, by DRIVER_TOPICS key."""
    return {key: getattr(args, f"{key}_topic") for key in DRIVER_TOPICS}


def overrides(args: argparse.Namespace) -> dict[str, dict[str, object]]:
    """Per node, the parameter values this run sets (on top of the node's params file)."""
    record = not args.no_record
    if args.robot:
        params = robot_overrides(args)
    else:
        expect = ["separator_node", "controller_node", "evaluator_node"] + (["recorder_node"] if record else [])
        params = {node: {} for node in NODES}
        params["sim_node"].update(task=args.task, sound_split=args.sound_split, num_episodes=args.episodes,
                                  first_episode=args.first, mode=args.mode, step_timeout_s=args.step_timeout,
                                  expect_nodes=expect)
        if args.world:
            params["sim_node"]["world"] = canonical_spec(args.world)
        if args.rate is not None:
            params["sim_node"]["rate_hz"] = args.rate
        params["evaluator_node"]["output_dir"] = str(args.out / "scores")
    if args.controller:
        params["controller_node"]["policy"] = args.controller
    if args.separator_checkpoint:
        params["separator_node"]["checkpoint"] = str(Path(args.separator_checkpoint).resolve())
    params["recorder_node"]["output"] = str(args.out / "bag")
    if args.robot:
        params["recorder_node"].update(robot_recording(driver_topics(args)))
    for name, value in (("topics", args.record_topics), ("exclude", args.record_exclude),
                        ("max_rate_hz", args.record_max_rate), ("compression", args.compression)):
        if value is not None:
            params["recorder_node"][name] = value
    if args.live_view is not None:
        params["live_view_node"] = {"port": args.live_view}
        if record:  # served from the recorder's process: it takes every recorded topic from the recorder
            params["recorder_node"]["live_view"] = True
    for item in args.set:
        node, sep, assignment = item.partition(".")
        name, eq, value = assignment.partition("=")
        if not sep or not eq or node not in params:
            raise SystemExit(f"run_pipeline: --set {item!r} must be NODE.PARAM=VALUE with NODE one of "
                             f"{', '.join(params)}")
        params[node][name] = yaml.safe_load(value)
    if not args.robot:  # what the evaluator's tables count against: fewer scored means a partial run
        params["evaluator_node"].setdefault("episodes", params["sim_node"]["num_episodes"])
    return params


def ros_value(value: object) -> str:
    """A Python value as a -p NAME:=VALUE right-hand side (YAML, as ros2 parses it)."""
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(map(str, value)) + "]"
    return str(value).lower() if isinstance(value, bool) else str(value)


def node_configs(params: dict[str, dict[str, object]]) -> dict:
    """The config each node will build (its params file + this run's values): a bad --set value, an
    unknown parameter or a wrong type fails here (ConfigError naming it), before any node starts."""
    configs = {}
    for node, values in params.items():
        path = ROOT / "params" / f"{node}.yaml"
        config_type = {**NODE_CONFIGS, **ROBOT_CONFIGS}[node]
        base = dataclasses.asdict(config_type.from_yaml(path, node))
        configs[node] = config_type.from_dict({**base, **values}, source=f"{path.name} with this run's values")
    return configs


def prepare_data(config) -> None:
    """What the sim needs before it starts: the sound library and the episode file."""
    from m2h_ros import sim_world

    sim_world.sim_episodes(config, sim_world.prepare_library(config))


def node_environment(environ: dict[str, str], *, robot: bool) -> dict[str, str]:
    """The nodes' environment. A simulated run keeps to itself (this host only, a random ROS domain, unless
    the environment names them), so two runs on one machine never meet; robot mode leaves both as ROS
    has them, so it finds the robot's drivers wherever ROS would (the same ROS_DOMAIN_ID, 0 when unset)."""
    env = dict(environ)
    if not robot:
        env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        env.setdefault("ROS_DOMAIN_ID", str(random.randint(1, 100)))
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(ROOT / "params" / "fastdds.xml"))
    return env


def launcher() -> list[str]:
    if shutil.which("ros2run"):
        return ["ros2run", "m2h_ros"]
    if shutil.which("ros2"):
        return ["ros2", "run", "m2h_ros"]
    raise SystemExit("run_pipeline: neither ros2run (source env.sh) nor ros2 is on PATH")


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def last_error(log: Path) -> str:
    lines = [line for line in log.read_text(errors="replace").splitlines() if "FATAL" in line or "ERROR" in line
             or "Error" in line]
    return lines[-1].strip() if lines else ""


def main(argv=None) -> int:
    args = parse_args(argv)
    # SIGTERM (kill, timeout, a batch system) stops the nodes as Ctrl-C does; a second Ctrl-C (or a held
    # one) cannot interrupt stopping them.
    stop_signals.install()
    args.out = (args.out or ROOT / "runs" / datetime.now().strftime("%Y%m%d-%H%M%S")).resolve()
    if (args.out / "bag").exists():
        raise SystemExit(f"run_pipeline: {args.out / 'bag'} exists; choose another --out")
    params = overrides(args)
    nodes = tuple(ROBOT_CONFIGS if args.robot else NODES)
    try:
        remaps = robot_remaps(driver_topics(args)) if args.robot else {}
    except M2HError as exc:
        raise SystemExit(f"run_pipeline: {exc}") from exc
    finisher = "episode_driver" if args.robot else "sim_node"  # its exit ends the run
    try:
        configs = node_configs(params)
        if not args.robot:
            prepare_data(configs["sim_node"])
    except M2HError as exc:
        raise SystemExit(f"run_pipeline: {exc}") from exc
    (args.out / "logs").mkdir(parents=True, exist_ok=True)
    env = node_environment(os.environ, robot=args.robot)
    print(f"[run] ROS_DOMAIN_ID={env.get('ROS_DOMAIN_ID', '0 (unset)')}, run directory {args.out}", flush=True)
    if args.live_view is not None:
        view = params["live_view_node"]  # --set may change the host or the port
        print(f"[run] live view: ws://{view.get('host', '127.0.0.1')}:{view['port']} (Foxglove: Open connection)",
              flush=True)
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    started = time.monotonic()
    interrupted = False
    try:
        in_recorder = {"live_view_node"} if params["recorder_node"].get("live_view") else set()
        for node in nodes:
            if ((node == "recorder_node" and args.no_record) or (node == "live_view_node" and args.live_view is None)
                    or node in in_recorder
                    or (node in MICROPHONES.values() and node != MICROPHONES[args.microphones])):
                continue
            logs[node] = args.out / "logs" / f"{node}.log"
            command = [*launcher(), node, "--ros-args"]
            for hosted in (node, *(in_recorder if node == "recorder_node" else ())):
                command += ["--params-file", str(ROOT / "params" / f"{hosted}.yaml")]
                for name in params[hosted]:  # typed as the config holds them: 5 for a float is 5.0, which ROS needs
                    # NODE:NAME: a process that runs two nodes gives each only its own parameters
                    command += ["-p", f"{hosted}:{name}:={ros_value(getattr(configs[hosted], name))}"]
            for topic, to in remaps.get(node, ()):
                command += ["-r", f"{topic}:={to}"]
            procs[node] = subprocess.Popen(command, stdout=logs[node].open("w"), stderr=subprocess.STDOUT,
                                           # Sessions of their own: a Ctrl-C reaches them in stop order
                                           env=env, start_new_session=True, cwd=ROOT,
                                           preexec_fn=stop_signals.stop_with(os.getpid()))
        while procs[finisher].poll() is None:
            early = [n for n, p in procs.items() if n != finisher and p.poll() is not None]
            if early:  # the run cannot go on: stop now rather than wait out the sim's step timeout
                print(f"[run] {', '.join(early)} exited during the run: stopping every node", flush=True)
                stop(procs[finisher])
                break
            time.sleep(0.2)
    except KeyboardInterrupt:
        interrupted = True
        print("[run] interrupted: stopping every node", flush=True)
        if "base_node" in procs:  # the robot first: zero velocity now, not after its move and the other nodes
            stop(procs["base_node"])
        if finisher in procs:
            stop(procs[finisher])
    finally:
        stop_signals.closing()
        unlisted = [n for n in procs if n not in STOP_ORDER and n != finisher]  # before the recorder
        for node in unlisted + [n for n in STOP_ORDER if n in procs]:
            stop(procs[node])
        if finisher in procs:
            stop(procs[finisher])
    elapsed = time.monotonic() - started
    failed = {n: p.returncode for n, p in procs.items() if p.returncode != 0}
    print(f"[run] finished in {elapsed:.1f} s", flush=True)
    for node, proc in procs.items():
        detail = "" if proc.returncode == 0 else f"  <- {last_error(logs[node])}"
        print(f"[run]   {node:16s} exit {proc.returncode}{detail}")
    table = args.out / "scores" / "results.md"
    if table.exists():
        print()
        print(table.read_text())
    print(f"[run] scores : {table if table.exists() else '(none)'}")
    plot = args.out / "scores" / "si_sdr_vs_step.png"
    print(f"[run] plot   : {plot if plot.exists() else '(none)'}")
    if "recorder_node" in procs and procs["recorder_node"].returncode == 0 and not configs["recorder_node"].keep_derived:
        try:
            print(f"[run] derived: {derive_bag(args.out / 'bag').summary}", flush=True)
        except BagError as exc:
            failed["m2h-derive"] = 1
            print(f"[run] m2h-derive: {exc}", file=sys.stderr)
    if not args.no_record:
        print(f"[run] bag    : {args.out / 'bag'}")
    print(f"[run] logs   : {args.out / 'logs'}")
    if failed:
        print(f"[run] FAILED: {', '.join(f'{n} (exit {c})' for n, c in failed.items())}", file=sys.stderr)
        return 1
    return 130 if interrupted else 0  # 128 + SIGINT, the shell's code for an interrupted command


if __name__ == "__main__":
    try:
        exit_code = main()
    except KeyboardInterrupt:  # while the data were prepared: no node was started yet
        exit_code = 130
    stop_signals.ignore()
    sys.exit(exit_code)
