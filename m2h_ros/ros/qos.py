"""Every QoS profile of the graph, the event callbacks that make QoS mismatches loud, and the wait for
reliable delivery before a node exits."""

import time

from rclpy.duration import Duration
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Step streams: nothing may be dropped. Transient-local with a deep history: a reader that matches
# a writer late (discovery between processes can lag seconds behind what the graph API already
# shows) still receives the steps published before, and a consumer outside the lockstep (the
# evaluator scores while the next steps run) may fall behind. The lockstep bounds both: the simulator
# waits for each episode's score before the next, and an episode has at most 101 observations.
STEP_HISTORY = 128
STEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=STEP_HISTORY, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Episode info is latched so a node that starts late still learns the current episode. Deeper than
# one: the sim may start episodes while the evaluator (and the separator) still work on earlier ones,
# up to max_evaluator_lag (<= 100) observations behind, i.e. up to 5 near-target episodes; with depth 1
# a lagging reader lost the info of an episode it had not reached yet, and its steps waited forever.
EPISODE_HISTORY = 8
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=EPISODE_HISTORY,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# What describes the whole episode (its map, the static frames): the last one, kept for late joiners
# (rviz's and Foxglove's "latched" / transient-local subscriptions).
LATEST = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
# tf2's own profile for /tf (tf2_ros.TransformBroadcaster).
TF = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.VOLATILE)
# The recorder must accept any publisher: best-effort + volatile is compatible with every offer.
RECORD = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)


# Only the incompatible-QoS event: rclpy's defaults add an incompatible-type handler to every endpoint,
# and each handler is one more entity the Python executor puts in its wait set on every wake-up.
def publisher_events(logger, topic: str) -> PublisherEventCallbacks:
    return PublisherEventCallbacks(incompatible_qos=lambda event: logger.warning(
        f"incompatible QoS on {topic}: a subscriber requests an incompatible "
        f"{event.last_policy_kind.name}; it will receive nothing"), use_default_callbacks=False)


def subscription_events(logger, topic: str) -> SubscriptionEventCallbacks:
    return SubscriptionEventCallbacks(incompatible_qos=lambda event: logger.warning(
        f"incompatible QoS on {topic}: a publisher offers an incompatible "
        f"{event.last_policy_kind.name}; nothing will arrive from it"), use_default_callbacks=False)


def wait_for_delivery(node, *, timeout_s: float) -> None:
    """Before the process goes: wait, at most ``timeout_s`` in all, until every reliable reader has
    acknowledged every sample of ``node``'s publishers, and warn naming the topics whose readers had not.
    A writer destroyed first takes the samples it still had to repair with it (seen under load: the
    recorder missed the last steps' odometry and poses while their audio had arrived; a base missed its
    last zero velocity)."""
    deadline = time.monotonic() + timeout_s  # one deadline for all: a gone reader costs it once
    pending = [p.topic_name for p in node.publishers if not p.wait_for_all_acked(
        Duration(nanoseconds=max(0, int((deadline - time.monotonic()) * 1e9))))]
    if pending:
        node.get_logger().warning(f"readers had not acknowledged every sample of {', '.join(pending)} "
                                  f"after {timeout_s:g} s; exiting all the same")
