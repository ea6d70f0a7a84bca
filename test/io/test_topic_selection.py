"""What a recording keeps: topics and patterns to record and to leave out, per-topic rate limits."""

import pytest

from m2h_ros.errors import ConfigError
from m2h_ros.io.topic_selection import TopicSelection, parse_rate_limits


def test_topics_patterns_and_exclusions():
    everything = TopicSelection()
    assert everything.records("/audio") and everything.records("/camera/rgb/image_raw")
    chosen = TopicSelection(topics=("camera/*", "/audio"), exclude=("/camera/depth/*",))
    assert chosen.records("/audio") and chosen.records("/camera/rgb/image_raw")
    assert not chosen.records("/camera/depth/image_raw") and not chosen.records("/odom")


def test_rate_limits_take_the_first_pattern_that_matches():
    limits = TopicSelection(max_rate_hz=("/camera/rgb/image_raw=2", "/camera/*=0.5"))
    assert limits.min_interval_ns("/camera/rgb/image_raw") == 500_000_000
    assert limits.min_interval_ns("/camera/depth/image_raw") == 2_000_000_000
    assert limits.min_interval_ns("/audio") is None


@pytest.mark.parametrize("item", ["/odom", "/odom=", "=2", "/odom=fast", "/odom=0", "/odom=-1", "/odom=inf"])
def test_a_malformed_rate_limit_is_named(item):
    with pytest.raises(ConfigError, match=f"max_rate_hz: '{item}' is not TOPIC=HZ"):
        parse_rate_limits([item])
