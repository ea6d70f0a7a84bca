"""Carrying out the discrete actions on a real base: one grid step forward or a 90-degree turn,
closed-loop on odometry, within speed and acceleration limits. ROS-free: the base node feeds it
odometry and sends what it returns; the bench and the test base drive it with :class:`KinematicBase`.

Each move gets a goal fixed at its start (from the pose then): a point ``step_m`` ahead, or the heading
turned by ``turn_rad``. The speed toward the goal follows a trapezoid (accelerate at the limit, cruise
at the speed limit, brake so that it reaches zero at the goal) and is rate-limited by the acceleration
limit; a forward move also steers back onto its line. A move ends DONE within its tolerances, BLOCKED
when it makes no progress for ``blocked_timeout_s``, ABORTED when odometry goes stale or it runs
past ``move_timeout_s``; at every end the commanded velocity is zero."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from m2h_ros.config import Config, setting
from m2h_ros.core.world.episodes import ACTION_NAMES, MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT
from m2h_ros.errors import ConfigError

DONE, BLOCKED, ABORTED = "done", "blocked", "aborted"


def wrap(angle: float) -> float:
    """``angle`` in [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class Pose2D:
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class MotionLimits(Config):
    """What a move may do and when it ends (base_node's parameters, params/base_node.yaml)."""

    step_m: float = setting(1.0, "length of one forward move (the navigation grid's cell: 1 m)", min=0.01, max=10.0)
    turn_deg: float = setting(90.0, "angle of one turn (the grid's: 90 degrees)", min=1.0, max=180.0)
    max_linear_speed: float = setting(0.3, "highest forward speed, m/s", min=0.01, max=5.0)
    max_angular_speed: float = setting(1.0, "highest turn rate, rad/s", min=0.01, max=10.0)
    max_linear_accel: float = setting(0.5, "m/s^2, speeding up and braking", min=0.01, max=20.0)
    max_angular_accel: float = setting(2.0, "rad/s^2, speeding up and braking", min=0.01, max=50.0)
    position_tolerance: float = setting(0.01, "a forward move is done within this many metres of its goal "
                                        "along its line", min=0.001, max=1.0)
    heading_tolerance: float = setting(0.01, "a turn is done within this many radians of its goal heading",
                                       min=0.001, max=1.0)
    linear_gain: float = setting(2.0, "1/s: speed per metre still to go, near the goal", min=0.01, max=100.0)
    angular_gain: float = setting(3.0, "1/s: turn rate per radian still to go, near the goal", min=0.01, max=100.0)
    lateral_gain: float = setting(2.0, "rad/m: steering back onto a forward move's line", min=0.0, max=100.0)
    blocked_timeout_s: float = setting(3.0, "a move that makes no progress (progress_m) for this long is "
                                       "BLOCKED", min=0.1, max=600.0)
    progress_m: float = setting(0.01, "what counts as progress: metres of a forward move, radians of a turn",
                                min=0.0001, max=1.0)
    move_timeout_s: float = setting(30.0, "a move not done after this long is ABORTED", min=0.1, max=3600.0)
    odom_timeout_s: float = setting(0.5, "odometry older than this during a move: zero velocity, the move "
                                    "ABORTED", min=0.01, max=60.0)

    @property
    def turn_rad(self) -> float:
        return math.radians(self.turn_deg)


@dataclass(frozen=True)
class Goal:
    action: int
    start: Pose2D
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class Outcome:
    status: str
    reason: str
    position_error: float
    heading_error: float
    duration: float


def goal_for(action: int, pose: Pose2D, limits: MotionLimits) -> Goal:
    if action == MOVE_FORWARD:
        return Goal(action, pose, pose.x + limits.step_m * math.cos(pose.yaw),
                    pose.y + limits.step_m * math.sin(pose.yaw), pose.yaw)
    if action in (TURN_LEFT, TURN_RIGHT):
        turn = limits.turn_rad if action == TURN_LEFT else -limits.turn_rad
        return Goal(action, pose, pose.x, pose.y, wrap(pose.yaw + turn))
    if action == STOP:
        return Goal(action, pose, pose.x, pose.y, pose.yaw)
    raise ConfigError(f"action {action} is not one of {', '.join(f'{i} {n}' for i, n in enumerate(ACTION_NAMES))}")


def errors(goal: Goal, pose: Pose2D) -> tuple[float, float]:
    """(distance to the goal point, heading error) of ``pose``."""
    return math.hypot(goal.x - pose.x, goal.y - pose.y), wrap(goal.yaw - pose.yaw)


def _toward(remaining: float, current: float, *, gain: float, speed: float, accel: float, dt: float) -> float:
    """The speed toward a goal ``remaining`` away (signed): trapezoid profile, rate-limited from ``current``."""
    wanted = math.copysign(min(speed, gain * abs(remaining), math.sqrt(2 * accel * abs(remaining))), remaining)
    return current + float(np.clip(wanted - current, -accel * dt, accel * dt))


class MoveExecutor:
    """One move at a time: :meth:`start` it, then call :meth:`update` with each odometry pose (or
    :meth:`tick` without one) and send the (linear, angular) velocity it returns until it reports an
    :class:`Outcome`."""

    def __init__(self, limits: MotionLimits):
        self.limits = limits
        self.goal: Goal | None = None
        self.velocity = (0.0, 0.0)
        self.started = self.updated = self.last_odom = 0.0
        self.best = math.inf  # the smallest remaining distance (or heading) so far
        self.best_at = 0.0

    @property
    def active(self) -> bool:
        return self.goal is not None

    def start(self, action: int, pose: Pose2D, now: float) -> Outcome | None:
        """Begin ``action`` from ``pose``; STOP is done at once (the base stays where it is)."""
        self.goal = goal_for(action, pose, self.limits)
        self.velocity = (0.0, 0.0)
        self.started = self.updated = self.last_odom = self.best_at = now
        self.best = math.inf
        return self._finish(DONE, "stop: no motion", pose, now) if action == STOP else None

    def remaining(self, pose: Pose2D) -> float:
        """What is left of the move: metres along the line of a forward move, radians of a turn."""
        goal = self.goal
        if goal.action == MOVE_FORWARD:
            return (goal.x - pose.x) * math.cos(goal.yaw) + (goal.y - pose.y) * math.sin(goal.yaw)
        return wrap(goal.yaw - pose.yaw)

    def update(self, pose: Pose2D, now: float) -> tuple[tuple[float, float], Outcome | None]:
        """The velocity to send after odometry ``pose`` at ``now``, and the outcome once the move ended."""
        self.last_odom = now
        goal, limits = self.goal, self.limits
        dt = min(max(now - self.updated, 0.0), 0.2)
        self.updated = now
        remaining = self.remaining(pose)
        if goal.action == MOVE_FORWARD:
            done = abs(remaining) <= limits.position_tolerance
        else:
            done = abs(remaining) <= limits.heading_tolerance
        if done:
            return (0.0, 0.0), self._finish(DONE, "reached the goal", pose, now)
        if abs(remaining) < self.best - limits.progress_m:
            self.best, self.best_at = abs(remaining), now
        elif now - self.best_at > limits.blocked_timeout_s:
            return (0.0, 0.0), self._finish(BLOCKED, f"no progress for {limits.blocked_timeout_s:g} s", pose, now)
        if now - self.started > limits.move_timeout_s:
            return (0.0, 0.0), self._finish(ABORTED, f"not done after {limits.move_timeout_s:g} s", pose, now)
        linear, angular = self.velocity
        if goal.action == MOVE_FORWARD:
            # Signed distance off the line (left positive), steered back while driving along it.
            lateral = -(goal.x - pose.x) * math.sin(goal.yaw) + (goal.y - pose.y) * math.cos(goal.yaw)
            heading_wanted = wrap(goal.yaw - pose.yaw + math.atan(limits.lateral_gain * lateral))
            linear = _toward(remaining, linear, gain=limits.linear_gain, speed=limits.max_linear_speed,
                             accel=limits.max_linear_accel, dt=dt)
            angular = _toward(heading_wanted, angular, gain=limits.angular_gain, speed=limits.max_angular_speed,
                              accel=limits.max_angular_accel, dt=dt)
        else:
            linear = _toward(0.0, linear, gain=limits.linear_gain, speed=0.0, accel=limits.max_linear_accel, dt=dt)
            angular = _toward(remaining, angular, gain=limits.angular_gain, speed=limits.max_angular_speed,
                              accel=limits.max_angular_accel, dt=dt)
        self.velocity = (linear, angular)
        return self.velocity, None

    def tick(self, now: float, pose: Pose2D | None) -> Outcome | None:
        """Between odometry messages: ABORTED (and zero velocity) once odometry is older than odom_timeout_s."""
        if self.goal is not None and now - self.last_odom > self.limits.odom_timeout_s:
            return self._finish(ABORTED, f"odometry stale: none for {self.limits.odom_timeout_s:g} s", pose, now)
        return None

    def cancel(self, reason: str, now: float) -> Outcome:
        """End the move now, ABORTED (a new command, the node shutting down)."""
        return self._finish(ABORTED, reason, None, now)

    def _finish(self, status: str, reason: str, pose: Pose2D | None, now: float) -> Outcome:
        distance, heading = errors(self.goal, pose) if pose is not None else (math.nan, math.nan)
        outcome = Outcome(status, reason, distance, heading, now - self.started)
        self.goal, self.velocity = None, (0.0, 0.0)
        return outcome


class KinematicBase:
    """A differential-drive base for tests and the bench: integrates the commanded (linear, angular)
    velocity, applied ``latency_s`` late, and reports odometry with Gaussian noise. ``wall_x``: the base
    cannot pass x = wall_x (a blocked move)."""

    def __init__(self, *, latency_s: float = 0.05, noise_m: float = 0.005, noise_rad: float = 0.005,
                 wall_x: float = math.inf, seed: int = 0):
        self.pose = Pose2D(0.0, 0.0, 0.0)
        self.latency_s = latency_s
        self.noise_m, self.noise_rad = noise_m, noise_rad
        self.wall_x = wall_x
        self.rng = np.random.default_rng(seed)
        self.pending: deque[tuple[float, tuple[float, float]]] = deque()
        self.applied = (0.0, 0.0)

    def command(self, velocity: tuple[float, float], now: float) -> None:
        self.pending.append((now + self.latency_s, velocity))

    def advance(self, now: float, dt: float) -> None:
        while self.pending and self.pending[0][0] <= now:
            self.applied = self.pending.popleft()[1]
        linear, angular = self.applied
        p = self.pose
        yaw = p.yaw + angular * dt / 2  # midpoint heading over the interval
        x = p.x + linear * dt * math.cos(yaw)
        self.pose = Pose2D(min(x, self.wall_x) if x > p.x else x, p.y + linear * dt * math.sin(yaw),
                           wrap(p.yaw + angular * dt))

    def odometry(self) -> Pose2D:
        p = self.pose
        return Pose2D(p.x + self.rng.normal(0, self.noise_m), p.y + self.rng.normal(0, self.noise_m),
                      wrap(p.yaw + self.rng.normal(0, self.noise_rad)))
