"""Publishers of derived products (spectrogram pictures, playable audio, the path, TF): a message is built
only while a subscriber is matched, as image_transport's publishers do, so a run that nobody watches and
whose recorder leaves them to ``m2h-derive`` pays nothing for them. Each counts what it sent, for the
node's summary at exit."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from rclpy.publisher import Publisher


class OnDemand:
    """``publish(build)``: ``build()``'s message (or serialized bytes) goes out if anyone subscribes now."""

    def __init__(self, publisher: Publisher) -> None:
        self.publisher = publisher
        self.published = 0

    @property
    def topic(self) -> str:
        return self.publisher.topic_name

    def publish(self, build: Callable[[], object]) -> bool:
        if not self.publisher.get_subscription_count():
            return False
        self.publisher.publish(build())
        self.published += 1
        return True


def on_demand_summary(publishers: Iterable[OnDemand | None]) -> str:
    """'derived topics sent (only while subscribed): /a 0, /b 12'."""
    counts = ", ".join(f"{p.topic} {p.published}" for p in publishers if p is not None)
    return f"derived topics sent (only while subscribed): {counts}"
