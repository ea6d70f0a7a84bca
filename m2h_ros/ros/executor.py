"""A single-threaded executor with a fraction of rclpy's Python work per wake-up.

rclpy's ``SingleThreadedExecutor`` rebuilds its wait set from every entity of every node on each
wake-up (an ``ExitStack`` entry, a filter and a membership test per entity) and runs each callback
as a ``Task`` coroutine: a node with 13 subscriptions (the recorder has 14) paid 1.3 ms of CPU per
received message, 0.6 ms with this executor (``scripts/bench/ros_messages.py``), and the recorder and
the evaluator wake up several times per pipeline step. ``StepExecutor`` keeps the entities, their handles and the wait set
between wake-ups (rebuilt only when a node's entities change) and calls every ready callback
directly, in the order rclpy would (waitables, timers, subscriptions, services).

It serves what the pipeline's nodes use: plain (not ``async``) callbacks of subscriptions, timers,
services and QoS event handlers, one thread. Anything else (service clients, guard conditions of a
node, tasks, coroutine callbacks) falls back to rclpy's own loop, so it is never wrong, only slower.
It reads rclpy internals (the executor's guard conditions and task list, a subscription's callback
type, an event handler's handle): written against rclpy 7.1.6 (Jazzy), pinned in requirements.txt;
test/graph/test_executor.py checks each kind of entity it serves.
"""

from __future__ import annotations

import inspect
import time
from contextlib import ExitStack

from rclpy.event_handler import EventHandler
from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription
from rclpy.utilities import timeout_sec_to_nsec


class _Entities:
    """The entities of the executor's nodes, their handles held and one wait set sized for them."""

    def __init__(self, executor: StepExecutor) -> None:
        nodes = executor.get_nodes()
        self.subscriptions = [s for n in nodes for s in n.subscriptions]
        self.timers = [t for n in nodes for t in n.timers]
        self.services = [s for n in nodes for s in n.services]
        waitables = [w for n in nodes for w in n.waitables]
        # QoS event handlers (one per endpoint, rarely ready) are polled through their event handles
        # directly: their Python add_to_wait_set / is_ready cost more than the rest of a wake-up.
        self.events = [(w, w._EventHandler__event) for w in waitables
                       if isinstance(w, EventHandler) and hasattr(w, "_EventHandler__event")]
        self.waitables = [w for w in waitables if not any(w is e for e, _ in self.events)]
        self.guards = [executor._guard, executor._sigint_gc]
        self.stack = ExitStack()
        for entity in (*self.subscriptions, *self.timers, *self.services, *self.guards):
            self.stack.enter_context(entity.handle)
        events = len(self.events)
        for waitable in waitables:
            self.stack.enter_context(waitable)
        for waitable in self.waitables:
            events += waitable.get_num_entities().num_events
        self.stack.enter_context(executor.context.handle)
        self.supported = _supported(nodes)
        self.wait_set = _rclpy.WaitSet(len(self.subscriptions), len(self.guards), len(self.timers), 0,
                                       len(self.services), events, executor.context.handle)

    def close(self) -> None:
        self.stack.close()


def _supported(nodes) -> bool:
    """True when every entity and callback of ``nodes`` is one StepExecutor runs itself."""
    for node in nodes:
        if list(node.clients) or list(node.guards):  # generators: always truthy themselves
            return False
        callbacks = [e.callback for e in (*node.subscriptions, *node.timers, *node.services)]
        if any(inspect.iscoroutinefunction(c) for c in callbacks):
            return False
    return True


class StepExecutor(SingleThreadedExecutor):
    """``SingleThreadedExecutor`` whose ``spin_once`` runs every callback ready after one wait."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._entities: _Entities | None = None
        self._entities_changed = True  # rclpy wakes a node's executor whenever it adds or removes an entity
        # Process CPU seconds when the first message arrived: a node's work from there on, without its
        # start-up (imports, models, discovery), is what a pipeline step costs.
        self.cpu_at_first_message: float | None = None

    def wake(self) -> None:
        self._entities_changed = True
        super().wake()

    def _current_entities(self) -> _Entities:
        if self._entities is None or self._entities_changed:
            self._release()
            self._entities_changed = False
            self._entities = _Entities(self)
        return self._entities

    def _release(self) -> None:
        if self._entities is not None:
            self._entities.close()
            self._entities = None

    def spin_once(self, timeout_sec: float | None = None) -> None:
        entities = self._current_entities()
        if self._tasks or not entities.supported:
            super().spin_once(timeout_sec)
            return
        wait_set = entities.wait_set
        wait_set.clear_entities()
        for sub in entities.subscriptions:
            wait_set.add_subscription(sub.handle)
        for timer in entities.timers:
            wait_set.add_timer(timer.handle)
        for service in entities.services:
            wait_set.add_service(service.handle)
        for guard in entities.guards:
            wait_set.add_guard_condition(guard.handle)
        for waitable in entities.waitables:
            waitable.add_to_wait_set(wait_set)
        event_indices = [wait_set.add_event(event) for _, event in entities.events]
        wait_set.wait(timeout_sec_to_nsec(timeout_sec))
        if self._is_shutdown:
            raise ShutdownException()
        if not self._context.ok():
            raise ExternalShutdownException()
        ready = [w for w in entities.waitables if w.is_ready(wait_set)]
        for (handler, _), index in zip(entities.events, event_indices):
            if wait_set.is_ready("event", index):
                handler._ready_to_take_data = True  # what its is_ready() would have set
                ready.append(handler)
        for waitable in ready:
            coroutine = waitable.execute(waitable.take_data())
            try:
                coroutine.send(None)  # QoS event handlers' execute() never awaits
            except StopIteration:
                pass
        timers_ready = wait_set.get_ready_entities("timer")
        subs_ready = wait_set.get_ready_entities("subscription")
        services_ready = wait_set.get_ready_entities("service")
        for timer in entities.timers:
            if timer.handle.pointer in timers_ready and timer.handle.is_timer_ready():
                timer.handle.call_timer()
                timer.callback()
        for sub in entities.subscriptions:
            if sub.handle.pointer in subs_ready:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
                if taken is not None:
                    if self.cpu_at_first_message is None:
                        self.cpu_at_first_message = time.process_time()
                    if sub._callback_type is Subscription.CallbackType.MessageOnly:
                        sub.callback(taken[0])
                    else:
                        sub.callback(*taken)
        for service in entities.services:
            if service.handle.pointer in services_ready:
                request, header = service.handle.service_take_request(service.srv_type.Request)
                if header is not None:
                    service.send_response(service.callback(request, service.srv_type.Response()), header)

    def remove_node(self, node) -> None:
        self._release()
        super().remove_node(node)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        self._release()
        return super().shutdown(timeout_sec)
