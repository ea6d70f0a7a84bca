"""A Foxglove WebSocket client, as the Foxglove app is one: it subscribes to the channels a live view
(``live_view_node``, foxglove_bridge) advertises and takes what they send. The tests check the live view
with it and the pipeline benchmark watches a run with it, without the app."""

from __future__ import annotations

import asyncio
import json
import struct
import time
from collections.abc import Collection
from dataclasses import dataclass, field

import websockets

SUBPROTOCOL = "foxglove.sdk.v1"  # the only one foxglove-sdk 0.30's server accepts
MESSAGE_DATA = 1  # binary opcode of a message on a subscribed channel
UNKNOWN_CHANNEL = "Unknown channel ID: "


@dataclass
class Watched:
    """What a client saw: the advertised channels by topic, and per topic the payloads it received
    (``keep``) or only their count and bytes."""

    channels: dict[str, dict] = field(default_factory=dict)
    payloads: dict[str, list[bytes]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    received_bytes: int = 0


async def _subscribe(ws, channel_ids: list[int]) -> None:
    """One subscription per channel, its id the channel's."""
    if channel_ids:
        await ws.send(json.dumps({"op": "subscribe",
                                  "subscriptions": [{"id": c, "channelId": c} for c in channel_ids]}))


async def _connect(url: str, deadline: float):
    """Connects, retrying until the server is up or ``deadline`` (monotonic) has passed."""
    while True:
        try:
            return await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None)
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)


async def watch(port: int, *, timeout: float, wanted: dict[str, int] | None = None,
                only: Collection[str] | None = None, keep: bool = True, host: str = "127.0.0.1") -> Watched:
    """Subscribes to every channel as it is advertised (or to those of the topics ``only`` names) and takes
    messages until each topic of ``wanted`` has its count, or, without ``wanted``, until the server
    closes; ``timeout`` seconds at most, connecting included."""
    deadline = time.monotonic() + timeout
    ws = await _connect(f"ws://{host}:{port}", deadline)
    seen, by_id = Watched(), {}

    def done() -> bool:
        return wanted is not None and all(seen.counts.get(t, 0) >= n for t, n in wanted.items())

    async with ws:
        while not done() and time.monotonic() < deadline:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            except websockets.ConnectionClosed:  # the run ended
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "advertise":
                    new = [c for c in op["channels"] if c["id"] not in by_id]
                    by_id.update({c["id"]: c for c in new})
                    await _subscribe(ws, [c["id"] for c in new if only is None or c["topic"] in only])
                elif op["op"] == "status" and op["message"].startswith(UNKNOWN_CHANNEL):
                    # foxglove-sdk can advertise a channel a moment before it accepts subscriptions to it
                    # (it answers "Unknown channel ID"): ask again, as a client that retries would.
                    await asyncio.sleep(0.05)
                    await _subscribe(ws, [int(op["message"][len(UNKNOWN_CHANNEL):])])
            elif frame[0] == MESSAGE_DATA:
                subscription, _ = struct.unpack_from("<IQ", frame, 1)  # subscription id = channel id here
                topic = by_id[subscription]["topic"]
                seen.counts[topic] = seen.counts.get(topic, 0) + 1
                seen.received_bytes += len(frame)
                if keep:
                    seen.payloads.setdefault(topic, []).append(frame[13:])
    seen.channels = {c["topic"]: c for c in by_id.values()}
    return seen
