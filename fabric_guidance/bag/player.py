"""Replay through the graph: republish a bag's recorded inputs (gaze, head_pose, target,
active_target) on their recorded QoS, paced by their timestamps, with /clock
(rosgraph_msgs/Clock) at the bag's time, so that nodes started with use_sim_time:=true run on
the bag's time. With loop, the bag plays again from its start: the clock jumps back.
Messages go out as recorded (serialized CDR, published raw): no decoding, no re-stamping.

Never into a live graph: before the first message and every RECHECK_S while playing, the
subscribers of every control topic it publishes (topics.CONTROL_TOPICS: the ones that move a
suit) are looked at; a pressure_controller on the wall clock (its use_sim_time false, or not
answering) or a plc_output in that namespace makes the replay stop with LiveGraphError (one
line, nothing more published), and so does a subscriber the graph has not named for `wait_s`
(a live controller also takes its target only from its own target_selector: docs/safety.md).
A replay's own controller runs with use_sim_time:=true, in a graph of its own or under a
namespace (`namespace`: every topic published under it).
"""
from __future__ import annotations

import time
from typing import Callable, Sequence

from ..interface import CLOCK_KIND, DEFAULT, qos_profile
from .reader import raw_messages
from .topics import CLOCK, REPLAYED_INPUTS, TOPICS, is_control_topic

#: /clock is published at least this often between messages [s].
CLOCK_PERIOD_S = 0.01
#: The graph is looked at again this often while playing [s]; a controller's use_sim_time is
#: asked for at most this long [s].
RECHECK_S, PARAMETER_TIMEOUT_S = 0.25, 2.0
#: Node names that make a namespace live: its controller, and the driver of its suit.
CONTROLLER, PLC_OUTPUT = 'pressure_controller', 'plc_output'


class LiveGraphError(RuntimeError):
    """A control topic of the replay would reach a live controller; the message says which."""


class LiveGuard:
    """Who would hear the replay's control topics (on the player's node, whose graph it reads)."""

    def __init__(self, node, topics):
        self.node = node
        self.topics = sorted(t for t in topics if is_control_topic(t))
        self._sim_time: dict[str, bool] = {}   # a controller's full name -> its use_sim_time
        self._unnamed_since: float | None = None   # a subscriber not named yet, seen first then

    def check(self, wait_s: float = 0.0) -> None:
        """Raise LiveGraphError when a control topic is heard in a live namespace, or by a
        subscriber whose node the graph has not named for wait_s (the graph names a node some
        time after its endpoints match, and may lose a name for a moment on a loaded machine:
        a fresh run's replay stopped at its second loop on an unnamed subscriber)."""
        unknown = self.look()
        if not unknown:
            self._unnamed_since = None
            return
        now = time.monotonic()
        if self._unnamed_since is None:
            self._unnamed_since = now
        if now - self._unnamed_since >= wait_s:
            raise LiveGraphError(self._refusal(unknown, 'a subscriber\'s node is not known (the graph '
                                                        'has not named it)'))

    def wait_known(self, wait_s: float) -> None:
        """check(), after waiting up to wait_s for every subscriber's node to be named (the graph
        names a node some time after its endpoints match)."""
        deadline = time.monotonic() + wait_s
        while self.look() and time.monotonic() < deadline:
            time.sleep(0.05)
        self.check()

    def look(self) -> str:
        """LiveGraphError for a live namespace; else the first topic with a subscriber not named
        yet ('' when every one is known)."""
        drivers = {ns for name, ns in self.node.get_node_names_and_namespaces() if name == PLC_OUTPUT}
        unknown = ''
        for topic in self.topics:
            namespace = topic.rsplit('/', 1)[0] or '/'
            if namespace in drivers:
                raise LiveGraphError(self._refusal(topic, f'{_join(namespace, PLC_OUTPUT)} drives a suit there'))
            for info in self.node.get_subscriptions_info_by_topic(topic):
                full = _join(info.node_namespace, info.node_name)
                if info.node_name == PLC_OUTPUT:
                    raise LiveGraphError(self._refusal(topic, f'{full} drives a suit there'))
                if info.node_name == CONTROLLER and not self._on_sim_time(full):
                    raise LiveGraphError(self._refusal(topic, f'{full} runs on the wall clock '
                                                              '(use_sim_time false): a live controller'))
                if info.node_name.startswith('_') or info.node_namespace.startswith('_'):
                    unknown = unknown or topic   # rmw's _NODE_NAME_UNKNOWN_: not named yet
        return unknown

    def _on_sim_time(self, full: str) -> bool:
        if full not in self._sim_time:
            from rcl_interfaces.srv import GetParameters
            import rclpy
            client = self.node.create_client(GetParameters, f'{full}/get_parameters')
            try:
                answer = None
                if client.wait_for_service(timeout_sec=PARAMETER_TIMEOUT_S):
                    future = client.call_async(GetParameters.Request(names=['use_sim_time']))
                    rclpy.spin_until_future_complete(self.node, future, timeout_sec=PARAMETER_TIMEOUT_S)
                    answer = future.result()
            finally:
                self.node.destroy_client(client)
            # No answer: taken for live (the safe side), and asked again at the next look.
            if answer is None or not answer.values:
                return False
            self._sim_time[full] = bool(answer.values[0].bool_value)
        return self._sim_time[full]

    @staticmethod
    def _refusal(topic: str, why: str) -> str:
        return (f'refusing to publish {topic}: {why}. A replay drives only a controller of its own (started '
                'with use_sim_time:=true): replay into another ROS_DOMAIN_ID, or under a namespace of its '
                'own with --namespace replay')


def _join(namespace: str, name: str) -> str:
    return f'{namespace.rstrip("/")}/{name}'


def _short(topic: str) -> str:
    return topic.lstrip('/')


def play(path, topics: Sequence[str] = REPLAYED_INPUTS, rate: float = 1.0, loop: bool = False, loops: int = 0,
         wait_s: float = 2.0, say: Callable[[str], None] = print, stop: Callable[[], bool] = lambda: False,
         namespace: str = '') -> int:
    """Republish `topics` of the bag with /clock (under `namespace` when given). loops > 0 ends
    after that many passes; with loop and loops == 0 it runs until interrupted. Returns the number
    of messages published; LiveGraphError before or while playing into a live graph."""
    import rclpy
    from rosgraph_msgs.msg import Clock
    import importlib

    if rate <= 0:
        raise ValueError(f'rate must be > 0, got {rate}')
    wanted = {t if t.startswith('/') else '/' + t for t in topics}
    recovered = []
    msgs = [(ts, topic, msgtype, data) for topic, msgtype, ts, data in raw_messages(path, wanted, None, recovered)]
    for r in recovered:
        say(r.describe())
    if not msgs:
        raise ValueError(f'{path}: none of {sorted(wanted)} recorded')
    msgs.sort(key=lambda m: m[0])
    prefix = '/' + '/'.join(p for p in namespace.split('/') if p) if namespace.strip('/') else ''
    rclpy.init()
    node = rclpy.create_node('bag_player')
    try:
        pubs = {}
        for _, topic, msgtype, _ in msgs:
            if topic not in pubs:
                package, _, name = msgtype.split('/')
                cls = getattr(importlib.import_module(f'{package}.msg'), name)
                kind = TOPICS.get(_short(topic), (None, DEFAULT))[1]
                pubs[topic] = node.create_publisher(cls, prefix + topic, qos_profile(kind))
        clock_pub = node.create_publisher(Clock, CLOCK, qos_profile(CLOCK_KIND))
        deadline = time.monotonic() + wait_s
        # Every publisher matched, /clock included: a node that hears the clock late would miss
        # the start of the bag (and, with a short bag, a whole loop).
        while time.monotonic() < deadline and not all(p.get_subscription_count()
                                                      for p in [*pubs.values(), clock_pub]):
            time.sleep(0.02)
        guard = LiveGuard(node, [prefix + t for t in pubs])
        guard.wait_known(wait_s)
        next_check = time.monotonic() + RECHECK_S
        t0, t_end = msgs[0][0], msgs[-1][0]
        where = f' under {prefix}' if prefix else ''
        say(f'replaying {len(msgs)} messages on {sorted(pubs)}{where} with /clock, {(t_end - t0) * 1e-9:.2f} s of '
            f'bag at rate {rate:g}{", looping" if loop else ""}; no live controller hears {guard.topics or "them"}')
        published = 0
        passes = 0

        def clock(ns: int) -> None:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(int(ns), 1_000_000_000)
            clock_pub.publish(c)

        while not stop():
            start = time.monotonic()
            for ts, topic, _, data in msgs:
                due = start + (ts - t0) * 1e-9 / rate
                while not stop():
                    now = time.monotonic()
                    if now >= due:
                        break
                    clock(t0 + int((now - start) * rate * 1e9))
                    time.sleep(min(CLOCK_PERIOD_S, due - now))
                if stop():
                    break
                if time.monotonic() >= next_check:   # a live controller started meanwhile
                    guard.check(wait_s)
                    next_check = time.monotonic() + RECHECK_S
                clock(ts)
                pubs[topic].publish(data)
                published += 1
            passes += 1
            if not loop or (loops and passes >= loops):
                break
            say(f'loop {passes + 1}: the clock jumps back to the start of the bag')
        return published
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
