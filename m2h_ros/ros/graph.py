"""Who listens to what: the simulator waits for its consumers before step 0 (volatile step topics
would otherwise drop the first messages), and checks the recorder has every pipeline topic."""

from __future__ import annotations

from rclpy.node import Node

from m2h_ros import topics
from m2h_ros.io.derived import absolute, derived_topics

# The topics each pipeline node must be subscribed to before the first step.
CONSUMERS = {
    "separator_node": (topics.AUDIO, topics.EPISODE),
    "controller_node": (topics.AUDIO, topics.ODOM, topics.EPISODE),  # + the separator's, if its controller reads them
    "evaluator_node": (topics.GROUND_TRUTH, topics.AUDIO, topics.AGENT_POSE, topics.EPISODE, topics.REFINED,
                       topics.COMMAND),
}
PIPELINE_TOPICS = tuple(value for name, value in vars(topics).items() if name.isupper() and isinstance(value, str))
# What a recorder may leave to m2h-derive (keep_derived: false): waited for only from a recorder that
# subscribes to one of them (keep_derived: true), so that it has every picture from step 0.
DERIVED = frozenset(derived_topics())


def missing_consumers(node: Node, expected: tuple[str, ...]) -> list[str]:
    """'node: topic, topic' for every expected node not yet subscribed to the topics it needs; the
    recorder needs every pipeline topic that has a publisher, the derived ones only if it records them."""
    subscribers: dict[str, set[str]] = {}
    published: list[str] = []
    for topic in PIPELINE_TOPICS:
        name = node.resolve_topic_name(topic)
        subscribers[topic] = {info.node_name for info in node.get_subscriptions_info_by_topic(name)}
        if node.get_publishers_info_by_topic(name):
            published.append(topic)
    keeps_derived = any("recorder_node" in subscribers[t] for t in PIPELINE_TOPICS if absolute(t) in DERIVED)
    recorded = [t for t in published if keeps_derived or absolute(t) not in DERIVED]
    missing = []
    for expected_node in expected:
        needed = recorded if expected_node == "recorder_node" else CONSUMERS[expected_node]
        lacking = [t for t in needed if expected_node not in subscribers[t]]
        if lacking:
            missing.append(f"{expected_node}: {', '.join(lacking)}")
    return missing
