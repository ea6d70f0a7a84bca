"""base_node: carries out each MotionCommand on a robot base, closed-loop on its odometry.

Forward one grid step or turn 90 degrees (m2h_ros.core.robot.base_motion: trapezoid speed profile
within the speed and acceleration limits, tolerances, blocked detection), sending
geometry_msgs/TwistStamped on cmd_vel (plain Twist with twist_stamped:=false) at the odometry's
rate. Each command ends with one m2h_msgs/MotionResult (DONE, BLOCKED or ABORTED) so the next step
can start, and with zero velocity: at the move's end, when odometry goes stale, when a move runs too
long, and when the node shuts down (Ctrl-C or SIGTERM). A command arriving during a move aborts that
move and starts the new one. STOP is done at once, without motion."""

from __future__ import annotations

import time

from geometry_msgs.msg import Twist, TwistStamped
from m2h_msgs.msg import MotionCommand, MotionResult
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from m2h_ros import topics
from m2h_ros.core.robot.base_motion import ABORTED, BLOCKED, DONE, MoveExecutor, Outcome, Pose2D
from m2h_ros.node_configs import BaseNodeConfig
from m2h_ros.ros import convert
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.qos import STEP, publisher_events, subscription_events, wait_for_delivery
from m2h_ros.ros.spin import run_node

TICK_S = 0.05  # how often stale odometry is looked for between odometry messages
STATUS = {DONE: MotionResult.DONE, BLOCKED: MotionResult.BLOCKED, ABORTED: MotionResult.ABORTED}
SHUTDOWN_DELIVERY_S = 1.0  # at shutdown, how long the last zero velocity and result may wait for acks


class BaseNode(Node):
    def __init__(self):
        super().__init__("base_node")
        self.config: BaseNodeConfig = declare_config(self, BaseNodeConfig)
        self.mover = MoveExecutor(self.config)
        self.command: MotionCommand | None = None  # the one being carried out
        self.pose: Pose2D | None = None
        self.odom_at = -float("inf")  # monotonic time of the last odometry
        self.held_since: float | None = None  # the command came without fresh odometry: it waits for some
        twist = TwistStamped if self.config.twist_stamped else Twist
        self.pub_cmd_vel = self.create_publisher(twist, topics.CMD_VEL, 10,
                                                 event_callbacks=publisher_events(self.get_logger(), topics.CMD_VEL))
        self.pub_result = self.create_publisher(MotionResult, topics.MOTION_RESULT, STEP,
                                                event_callbacks=publisher_events(self.get_logger(), topics.MOTION_RESULT))
        # Best effort matches a base driver's odometry whether it publishes reliably or not.
        self.create_subscription(Odometry, topics.ODOM, self.on_odom, qos_profile_sensor_data,
                                 event_callbacks=subscription_events(self.get_logger(), topics.ODOM))
        self.create_subscription(MotionCommand, topics.COMMAND, self.on_command, STEP,
                                 event_callbacks=subscription_events(self.get_logger(), topics.COMMAND))
        self.create_timer(TICK_S, self.tick)
        cfg = self.config
        self.get_logger().info(f"ready: {cfg.step_m:g} m steps, {cfg.turn_deg:g} degree turns, at most "
                               f"{cfg.max_linear_speed:g} m/s and {cfg.max_angular_speed:g} rad/s, "
                               f"{'TwistStamped' if cfg.twist_stamped else 'Twist'} on {self.pub_cmd_vel.topic_name}")

    def on_command(self, msg: MotionCommand) -> None:
        now = time.monotonic()
        superseded = f"superseded by the command for step {msg.step}"
        if self.mover.active:
            self.finish(self.mover.cancel(superseded, now))
        elif self.held_since is not None:
            self.finish(Outcome(ABORTED, superseded, float("nan"), float("nan"), now - self.held_since))
        self.command = msg
        if now - self.odom_at > self.config.odom_timeout_s:  # none yet, or stale: no move without fresh odometry
            self.held_since = now
            return
        self.begin(now)

    def begin(self, now: float) -> None:
        outcome = self.mover.start(self.command.action, self.pose, now)
        if outcome is not None:
            self.finish(outcome)

    def on_odom(self, msg: Odometry) -> None:
        x, y, yaw = (float(v) for v in convert.pose_from_odometry(msg))
        self.pose, self.odom_at = Pose2D(x, y, yaw), time.monotonic()
        if self.held_since is not None:
            self.held_since = None
            self.begin(self.odom_at)
        elif self.mover.active:
            (linear, angular), outcome = self.mover.update(self.pose, self.odom_at)
            self.send(linear, angular)
            if outcome is not None:
                self.finish(outcome)

    def tick(self) -> None:
        now = time.monotonic()
        if self.held_since is not None:
            # Odometry that stopped: odom_timeout_s. None yet (the driver's discovery can lag seconds
            # behind start-up): as long as a move may take.
            wait = self.config.odom_timeout_s if self.odom_at > -float("inf") else self.config.move_timeout_s
            if now - self.held_since > wait:
                self.finish(Outcome(ABORTED, f"no odometry on {self.resolve_topic_name(topics.ODOM)} within {wait:g} s of the command",
                                    float("nan"), float("nan"), now - self.held_since))
            return
        outcome = self.mover.tick(now, self.pose)
        if outcome is not None:
            self.finish(outcome)

    def send(self, linear: float, angular: float) -> None:
        twist = Twist()
        twist.linear.x, twist.angular.z = float(linear), float(angular)
        if self.config.twist_stamped:
            msg = TwistStamped(twist=twist)
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.header.frame_id = self.config.frame_id
            self.pub_cmd_vel.publish(msg)
        else:
            self.pub_cmd_vel.publish(twist)

    def finish(self, outcome: Outcome) -> None:
        """The command's end: zero velocity, then its MotionResult."""
        self.send(0.0, 0.0)
        command, self.command, self.held_since = self.command, None, None
        result = MotionResult(episode_id=command.episode_id, step=command.step, action=command.action,
                              status=STATUS[outcome.status], reason=outcome.reason,
                              position_error=outcome.position_error, heading_error=outcome.heading_error,
                              duration=outcome.duration)
        result.header.stamp = self.get_clock().now().to_msg()
        self.pub_result.publish(result)
        line = f"{command.episode_id} step {command.step}: {outcome.status} ({outcome.reason}) in {outcome.duration:.2f} s"
        # Two call sites: rclpy refuses one logging call that changes its severity between calls.
        if outcome.status == DONE:
            self.get_logger().info(line)
        else:
            self.get_logger().warning(line)

    def destroy_node(self) -> None:
        self.send(0.0, 0.0)  # run_node keeps the context alive until here (publish_on_shutdown)
        if self.command is not None:
            self.finish(self.mover.cancel("base_node shut down", time.monotonic()))
        # The process ends right after (without this wait the base missed the zero in 2 of 5 shutdowns under load)
        wait_for_delivery(self, timeout_s=SHUTDOWN_DELIVERY_S)
        super().destroy_node()


def main(args=None):
    run_node(BaseNode, args, publish_on_shutdown=True)


if __name__ == "__main__":
    main()
