"""The move executor base_node runs, closed-loop on an exact kinematic base: a left turn is
counter-clockwise (positive yaw rate, REP 103) and a right turn clockwise, a forward move covers a true
step_m along the heading, and no command exceeds the speed or acceleration limits."""

import math

import numpy as np
import pytest

from m2h_ros.core.robot.base_motion import (ABORTED, BLOCKED, DONE, KinematicBase, MotionLimits, MoveExecutor, Pose2D,
                                            goal_for)
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT

DT = 0.02  # odometry at 50 Hz
LIMITS = MotionLimits()


def run_move(action: int, start: Pose2D, *, limits: MotionLimits = LIMITS, wall_x: float = math.inf,
             odometry_until: float = math.inf):
    """Play one move to its end: (outcome, final true pose, commanded velocities in order)."""
    base = KinematicBase(latency_s=0.0, noise_m=0.0, noise_rad=0.0, wall_x=wall_x)
    base.pose = start
    mover = MoveExecutor(limits)
    now = 0.0
    outcome = mover.start(action, base.odometry(), now)
    sent = []
    while outcome is None:
        now += DT
        base.advance(now, DT)
        if now <= odometry_until:
            velocity, outcome = mover.update(base.odometry(), now)
            sent.append(velocity)
            base.command(velocity, now)
        else:
            outcome = mover.tick(now, None)
        assert now < 120, "the move never ended"
    return outcome, base.pose, np.array(sent)


@pytest.mark.parametrize("yaw", [0.0, 2.0, -3.0])
def test_a_left_turn_is_counter_clockwise_and_a_right_turn_clockwise(yaw):
    start = Pose2D(1.0, -2.0, yaw)
    assert goal_for(TURN_LEFT, start, LIMITS).yaw == pytest.approx(math.remainder(yaw + math.pi / 2, 2 * math.pi))
    assert goal_for(TURN_RIGHT, start, LIMITS).yaw == pytest.approx(math.remainder(yaw - math.pi / 2, 2 * math.pi))
    for action, sign in ((TURN_LEFT, 1.0), (TURN_RIGHT, -1.0)):
        outcome, end, sent = run_move(action, start)
        assert outcome.status == DONE
        turned = math.remainder(end.yaw - yaw, 2 * math.pi)
        assert turned == pytest.approx(sign * math.pi / 2, abs=2 * LIMITS.heading_tolerance)
        assert (sign * sent[:, 1] >= 0).all() and (sign * sent[:, 1]).max() > 0  # never the wrong way
        assert np.abs(sent[:, 0]).max() == 0.0  # a turn in place
        assert (end.x, end.y) == pytest.approx((start.x, start.y))


@pytest.mark.parametrize("yaw", [0.0, math.pi / 2, -2.5])
def test_a_forward_move_covers_a_true_step_along_its_heading(yaw):
    start = Pose2D(0.5, 0.25, yaw)
    outcome, end, sent = run_move(MOVE_FORWARD, start)
    assert outcome.status == DONE
    assert math.hypot(end.x - start.x, end.y - start.y) == pytest.approx(LIMITS.step_m, abs=2 * LIMITS.position_tolerance)
    goal = (start.x + math.cos(yaw), start.y + math.sin(yaw))
    assert (end.x, end.y) == pytest.approx(goal, abs=2 * LIMITS.position_tolerance)
    assert (sent[:, 0] >= 0).all()  # forward only


@pytest.mark.parametrize("action", [MOVE_FORWARD, TURN_LEFT, TURN_RIGHT])
def test_no_command_exceeds_the_speed_or_acceleration_limits(action):
    limits = MotionLimits(max_linear_speed=0.2, max_angular_speed=0.6, max_linear_accel=0.3, max_angular_accel=1.2)
    outcome, _, sent = run_move(action, Pose2D(0.0, 0.0, 0.3), limits=limits)
    assert outcome.status == DONE
    speeds = np.vstack([[0.0, 0.0], sent])  # from standing still
    assert np.abs(speeds[:, 0]).max() <= limits.max_linear_speed + 1e-9
    assert np.abs(speeds[:, 1]).max() <= limits.max_angular_speed + 1e-9
    steps = np.abs(np.diff(speeds, axis=0))
    assert steps[:-1, 0].max() <= limits.max_linear_accel * DT + 1e-9  # the last: the zero at the end
    assert steps[:-1, 1].max() <= limits.max_angular_accel * DT + 1e-9
    # It does reach its cruise speed (a 1 m move, a 90-degree turn are long enough).
    column = 0 if action == MOVE_FORWARD else 1
    cruise = limits.max_linear_speed if action == MOVE_FORWARD else limits.max_angular_speed
    assert np.abs(speeds[:, column]).max() == pytest.approx(cruise)


def test_a_wall_blocks_stale_odometry_aborts_and_stop_does_not_move():
    outcome, end, _ = run_move(MOVE_FORWARD, Pose2D(0.0, 0.0, 0.0), wall_x=0.4)
    assert outcome.status == BLOCKED and end.x == pytest.approx(0.4)
    outcome, _, _ = run_move(MOVE_FORWARD, Pose2D(0.0, 0.0, 0.0), odometry_until=1.0)
    assert outcome.status == ABORTED and "odometry stale" in outcome.reason
    outcome, end, sent = run_move(STOP, Pose2D(3.0, 1.0, 1.0))
    assert outcome.status == DONE and end == Pose2D(3.0, 1.0, 1.0) and len(sent) == 0
