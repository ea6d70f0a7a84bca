"""Every QoS profile of the graph, and the event callbacks that make QoS mismatches loud."""

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Step streams: nothing may be dropped. Keep-all, because a consumer outside the lockstep (the
# evaluator scores while the next steps run) can fall several steps behind; the lockstep bounds it:
# the simulator waits for each episode's score before starting the next.
STEP = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.VOLATILE)
# Episode info is latched so a node that starts late still learns the current episode.
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The recorder must accept any publisher: best-effort + volatile is compatible with every offer.
RECORD = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)


def publisher_events(logger, topic: str) -> PublisherEventCallbacks:
    return PublisherEventCallbacks(incompatible_qos=lambda event: logger.warning(
        f"incompatible QoS on {topic}: a subscriber requests an incompatible "
        f"{event.last_policy_kind.name}; it will receive nothing"))


def subscription_events(logger, topic: str) -> SubscriptionEventCallbacks:
    return SubscriptionEventCallbacks(incompatible_qos=lambda event: logger.warning(
        f"incompatible QoS on {topic}: a publisher offers an incompatible "
        f"{event.last_policy_kind.name}; nothing will arrive from it"))
