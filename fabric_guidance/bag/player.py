"""Replay through the graph: republish a bag's recorded inputs (gaze, head_pose, target,
active_target) on their recorded QoS, paced by their timestamps, with /clock
(rosgraph_msgs/Clock) at the bag's time, so that nodes started with use_sim_time:=true run on
the bag's time. With loop, the bag plays again from its start: the clock jumps back.
Messages go out as recorded (serialized CDR, published raw): no decoding, no re-stamping.
"""
from __future__ import annotations

import time
from typing import Callable, Sequence

from ..interface import CLOCK_KIND, DEFAULT, qos_profile
from .reader import raw_messages
from .topics import CLOCK, REPLAYED_INPUTS, TOPICS

#: /clock is published at least this often between messages [s].
CLOCK_PERIOD_S = 0.01


def _short(topic: str) -> str:
    return topic.lstrip('/')


def play(path, topics: Sequence[str] = REPLAYED_INPUTS, rate: float = 1.0, loop: bool = False, loops: int = 0,
         wait_s: float = 2.0, say: Callable[[str], None] = print, stop: Callable[[], bool] = lambda: False) -> int:
    """Republish `topics` of the bag with /clock. loops > 0 ends after that many passes; with
    loop and loops == 0 it runs until interrupted. Returns the number of messages published."""
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
    rclpy.init()
    node = rclpy.create_node('bag_player')
    try:
        pubs = {}
        for _, topic, msgtype, _ in msgs:
            if topic not in pubs:
                package, _, name = msgtype.split('/')
                cls = getattr(importlib.import_module(f'{package}.msg'), name)
                kind = TOPICS.get(_short(topic), (None, DEFAULT))[1]
                pubs[topic] = node.create_publisher(cls, topic, qos_profile(kind))
        clock_pub = node.create_publisher(Clock, CLOCK, qos_profile(CLOCK_KIND))
        deadline = time.monotonic() + wait_s
        # Every publisher matched, /clock included: a node that hears the clock late would miss
        # the start of the bag (and, with a short bag, a whole loop).
        while time.monotonic() < deadline and not all(p.get_subscription_count()
                                                      for p in [*pubs.values(), clock_pub]):
            time.sleep(0.02)
        t0, t_end = msgs[0][0], msgs[-1][0]
        say(f'replaying {len(msgs)} messages on {sorted(pubs)} with /clock, {(t_end - t0) * 1e-9:.2f} s of bag'
            f' at rate {rate:g}{", looping" if loop else ""}')
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
