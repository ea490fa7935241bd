"""Throttled logging decided before rclpy is called.

rclpy's throttle_duration_sec filter runs after the logger has looked up its caller
(inspect.getframeinfo reads the caller's source lines), so a call it throttles out costs
about as much as one it prints: hundreds of microseconds, per sample when a fault repeats on
every message. LogThrottle says whether a line is due first; the message is then not even
formatted while it is throttled.
"""
from __future__ import annotations

import time


class LogThrottle:
    """At most one line per `period_s` (steady clock) for each key."""

    def __init__(self, period_s: float):
        self.period_s = period_s
        self._next: dict[str, float] = {}

    def due(self, key: str) -> bool:
        now = time.monotonic()
        if now < self._next.get(key, 0.0):
            return False
        self._next[key] = now + self.period_s
        return True
