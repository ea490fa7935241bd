"""plc_output's part in a stop of the whole system: the PLC's vent latch (docs/plc.md, "Vent
request"; docs/safety.md, "A stop from any connection").

- **Kept out.** Another Modbus client holds the PLC's write claim: plc_output's writes are
  refused with exception 06. Within the PLC watchdog's time that can be plc_output's own earlier
  connection, not yet seen closed; for two watchdog times, it is a live client of its own (a tool left running,
  a second suit's plc_output on the same address). plc_output then writes the vent request
  (taken from any client, claim or not), reads the holder's address from the PLC and reports
  ERROR naming it.
- **A latch is a stop for the whole system.** A latch seen on a PLC, whoever set it (plc_output
  included), calls the controller's `vent`: the operator's arm drops there, and only the
  operator's `enable` lifts it. The study session sees the arm drop as any outside vent.
- **Re-arm.** Only the claim's holder can release the latch, and plc_output does so only for a
  command with pressure that its controller sent after answering that `vent`: the controller
  sends pressure only while the operator's arm is open, which after that `vent` takes the
  operator's `enable`. Its ordinary writes never re-arm; nor does a restart of plc_output (the
  latch is in the PLC, and the first cycle reads it again).

KeptOut and StopRelay are plain Python; VentLatch is plc_output's side of it (mixed into PlcOutput:
its links, its logger, the client of the controller's vent).
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
from std_srvs.srv import Trigger

from fabric_guidance.interface import VENT
from fabric_guidance.plc import PlcLinkError

#: The errors and warnings below are logged at most this often [s].
LOG_THROTTLE_S = 1.0
#: Kept out (06) this many PLC watchdog times, another client holds the PLC. The PLC frees a
#: claim of this node's own dead connection one watchdog time after its last heartbeat, and the
#: node is refused only after it has given that connection up (a request timeout later); the
#: second watchdog time is margin for a loaded PLC host's scan.
KEPT_OUT_WATCHDOGS = 2
#: The PLC's vent latch is read at most this often [s]: the PLC vents at the request by itself;
#: the read only tells the controller and the diagnostics, so it need not cost a request a cycle.
LATCH_READ_S = 0.1


class KeptOut:
    """One link's view of another client's write claim and of the PLC's vent latch."""

    def __init__(self):
        self.since: float | None = None   #: monotonic time of the first 06 of this refusal streak
        self.holder = ''                  #: the claim holder's address, as the PLC gives it
        self.vent_requests = 0            #: vent requests written (all streaks)
        self.latched = False              #: the PLC's vent latch at the last read
        self.requested = False            #: a vent request written in this streak
        self.next_latch_read = 0.0        #: monotonic time of the next read of the latch

    def refused(self, busy: bool, now_s: float) -> None:
        """A failed request: `busy` when it was exception 06 (another client's claim)."""
        if not busy:
            self.since, self.requested = None, False
        elif self.since is None:
            self.since = now_s

    def up(self) -> None:
        self.since, self.holder, self.requested = None, '', False

    def overdue(self, now_s: float, watchdog_s: float) -> bool:
        """Kept out for KEPT_OUT_WATCHDOGS PLC watchdog times: not an old connection of this node's."""
        return self.since is not None and now_s - self.since >= KEPT_OUT_WATCHDOGS * watchdog_s

    def describe(self, now_s: float) -> str:
        who = f'another client at {self.holder}' if self.holder else 'another client'
        held = '' if self.since is None else f' for {now_s - self.since:.1f} s'
        sent = (f'; vent request written ({self.vent_requests})' if self.vent_requests
                else '; vent request not written yet')
        return f'held by {who}{held} (exception 06){sent}'


class StopRelay:
    """When to call the controller's `vent`, and when a latched PLC may be re-armed.

    `stop()` whenever a latch (or a vent request of this node) is newly seen; `due()` says a
    call should go out (one at a time); `answered()` takes its result. `may_rearm()` is the
    re-arm rule above, on the command's send time by the wall clock (the publisher's source
    timestamp), compared with the time the answer arrived: a command sent before it may have
    left the controller before the controller vented.
    """

    def __init__(self, wall: Callable[[], float]):
        self._wall = wall
        self.wanted = False                 #: a stop the controller has not answered yet
        self.reason = ''
        self.told_at: float | None = None   #: wall time the controller's vent was answered
        self.calls = self.failures = 0
        self._generation = 0
        self._in_flight: int | None = None   #: the generation of the call out

    def stop(self, reason: str) -> None:
        self.wanted, self.reason, self.told_at = True, reason, None
        self._generation += 1

    def due(self) -> bool:
        return self.wanted and self._in_flight is None

    def sending(self) -> None:
        """A vent call goes out now."""
        self._in_flight = self._generation
        self.calls += 1

    def answered(self, success: bool) -> None:
        generation, self._in_flight = self._in_flight, None
        if not success:
            self.failures += 1
            return
        if generation == self._generation:   # no newer stop since it went out
            self.wanted, self.told_at = False, self._wall()

    def may_rearm(self, command: np.ndarray, sent_wall_s: float | None) -> bool:
        return (self.told_at is not None and sent_wall_s is not None and sent_wall_s > self.told_at
                and bool(np.any(command > 0.0)))


class VentLatch:
    """plc_output's methods for the vent latch (mixed into PlcOutput; `self` is the node, with
    its `_links`, `_relay`, `_controller_vent`, `_command_sent_wall` and `plc_watchdog_s`)."""

    def vent_client(self, controller: str):
        """The client of the controller's vent service (`controller`: its full node name)."""
        return self.create_client(Trigger, f'{controller}/{VENT.removeprefix("~/")}')

    def _request_vent(self, link) -> None:
        """Another client has held the PLC longer than its watchdog: the vent request (taken
        from any client), and its address for the diagnostics."""
        kept = link.kept_out
        if link.client.map.vent_register is None:
            return
        try:
            link.client.request_vent()
            kept.holder = link.client.read_claim_holder()
        except PlcLinkError as exc:
            self.get_logger().error(f'PLC {link.name}: cannot write the vent request: {exc}',
                                    throttle_duration_sec=LOG_THROTTLE_S)
            return
        kept.vent_requests += 1
        self.get_logger().error(f'PLC {link.name} {kept.describe(time.monotonic())}: the suit is '
                                'vented until the operator enables guidance again',
                                throttle_duration_sec=LOG_THROTTLE_S)
        if not kept.requested:   # once per streak: a stop, not one per retry
            kept.requested = True
            self._relay.stop(f'PLC {link.name} {kept.describe(time.monotonic())}')

    def _read_latch(self, link) -> None:
        """The PLC's vent latch; newly set (by anyone), it stops the controller too."""
        now = time.monotonic()
        if link.client.map.vent_register is None or now < link.kept_out.next_latch_read:
            return
        link.kept_out.next_latch_read = now + LATCH_READ_S
        latched = link.client.read_vent_latched()
        if latched and not link.kept_out.latched:
            self._relay.stop(f'the vent latch of PLC {link.name} is set')
            self.get_logger().warning(f'PLC {link.name}: vent latch set (a vent request); calling the '
                                      "controller's vent: the operator's enable lifts it")
        link.kept_out.latched = latched

    def _maybe_rearm(self, link, target: np.ndarray) -> None:
        """Release a latched PLC for a command with pressure sent after the controller vented."""
        if not link.kept_out.latched or not self._relay.may_rearm(target, self._command_sent_wall):
            return
        link.client.rearm()
        link.kept_out.latched = False
        self.get_logger().info(f'PLC {link.name}: vent latch released (the controller guides again '
                               "after the operator's enable)")

    def _tell_controller(self) -> None:
        """Call the controller's vent for a stop it has not answered yet (one call at a time)."""
        if not self._relay.due() or self._controller_vent is None:
            return
        if not self._controller_vent.service_is_ready():
            self.get_logger().warning(f'{self._relay.reason}: the controller\'s vent '
                                      f'({self._controller_vent.srv_name}) is not there yet; retrying',
                                      throttle_duration_sec=LOG_THROTTLE_S)
            return
        self._relay.sending()
        self._controller_vent.call_async(Trigger.Request()).add_done_callback(self._on_vent_answer)

    def _on_vent_answer(self, future) -> None:
        try:
            ok = bool(future.result().success)
        except Exception:  # noqa: BLE001 - a failed call is retried, whatever the cause
            ok = False
        self._relay.answered(ok)
        if ok:
            self.get_logger().warning(f'controller vented: {self._relay.reason}')
