#!/usr/bin/env python3
"""The base node's control law on a simulated base: final errors and time per move at the default limits.

Drives m2h_ros.core.robot.base_motion.MoveExecutor (what base_node runs, at its odometry rate) against
KinematicBase (the test base: the twist applied --latency late, odometry with Gaussian noise), in
simulated time, for --moves moves alternating 1 m steps and 90-degree turns left and right. Prints, per
kind of move, the final position error (metres from the goal point, true pose) and heading error
(degrees) as median and p95, and the time per move next to the ideal one at the limits (accelerate,
cruise, brake: the reference measured in the same run).

    .venv/bin/python scripts/bench/base_motion.py [--moves 96] [--latency 0.05] [--noise-m 0.005]
        [--noise-rad 0.005] [--odom-hz 20]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from m2h_ros.core.robot.base_motion import DONE, KinematicBase, MotionLimits, MoveExecutor, errors
from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT, TURN_RIGHT

SUBSTEP_S = 0.002  # integration step of the simulated base


def ideal_time(distance: float, speed: float, accel: float) -> float:
    """Accelerate at ``accel`` to ``speed``, cruise, brake: the fastest move within the limits."""
    if distance < speed**2 / accel:  # never reaches the speed limit
        return 2 * math.sqrt(distance / accel)
    return distance / speed + speed / accel


def run(args: argparse.Namespace) -> dict[str, list[tuple[float, float, float]]]:
    limits = MotionLimits()
    base = KinematicBase(latency_s=args.latency, noise_m=args.noise_m, noise_rad=args.noise_rad, seed=args.seed)
    executor = MoveExecutor(limits)
    period = 1.0 / args.odom_hz
    order = (MOVE_FORWARD, TURN_LEFT, MOVE_FORWARD, TURN_RIGHT)
    results: dict[str, list[tuple[float, float, float]]] = {"step": [], "turn": []}
    now = 0.0
    for k in range(args.moves):
        action = order[k % len(order)]
        executor.start(action, base.odometry(), now)
        goal = executor.goal
        next_odom = now
        outcome = None
        while outcome is None:
            if now >= next_odom:
                velocity, outcome = executor.update(base.odometry(), now)
                base.command(velocity, now)
                next_odom += period
            base.advance(now, SUBSTEP_S)
            now += SUBSTEP_S
        for _ in range(int(1.0 / SUBSTEP_S)):  # settle: the zero command arrives after the latency
            base.advance(now, SUBSTEP_S)
            now += SUBSTEP_S
        if outcome.status != DONE:
            raise SystemExit(f"move {k} ({action}) ended {outcome.status}: {outcome.reason}")
        distance, heading = errors(goal, base.pose)
        results["step" if action == MOVE_FORWARD else "turn"].append((distance, math.degrees(abs(heading)),
                                                                      outcome.duration))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moves", type=int, default=96)
    parser.add_argument("--latency", type=float, default=0.05, help="seconds before a twist takes effect")
    parser.add_argument("--noise-m", type=float, default=0.005, help="odometry position noise (std, metres)")
    parser.add_argument("--noise-rad", type=float, default=0.005, help="odometry heading noise (std, radians)")
    parser.add_argument("--odom-hz", type=float, default=20.0, help="odometry rate (the control rate)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    limits = MotionLimits()
    results = run(args)
    print(f"{args.moves} moves, latency {args.latency * 1000:.0f} ms, odometry noise {args.noise_m * 1000:.1f} mm / "
          f"{args.noise_rad:.3f} rad at {args.odom_hz:g} Hz; default limits {limits.max_linear_speed} m/s, "
          f"{limits.max_linear_accel} m/s^2, {limits.max_angular_speed} rad/s, {limits.max_angular_accel} rad/s^2")
    ideal = {"step": ideal_time(limits.step_m, limits.max_linear_speed, limits.max_linear_accel),
             "turn": ideal_time(limits.turn_rad, limits.max_angular_speed, limits.max_angular_accel)}
    print(f"{'move':5s} {'n':>3s} {'position error mm':>22s} {'heading error deg':>22s} {'time s':>16s} {'ideal s':>8s}")
    print(f"{'':5s} {'':>3s} {'median':>11s}{'p95':>11s} {'median':>11s}{'p95':>11s} {'median':>8s}{'p95':>8s}")
    for kind, rows in results.items():
        data = np.array(rows)
        pos, head, time_s = data[:, 0] * 1000, data[:, 1], data[:, 2]
        print(f"{kind:5s} {len(rows):3d} {np.median(pos):11.1f}{np.percentile(pos, 95):11.1f} "
              f"{np.median(head):11.2f}{np.percentile(head, 95):11.2f} {np.median(time_s):8.2f}"
              f"{np.percentile(time_s, 95):8.2f} {ideal[kind]:8.2f}")


if __name__ == "__main__":
    main()
