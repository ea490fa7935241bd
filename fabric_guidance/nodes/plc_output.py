"""plc_output: pressure commands (kPa, channel order) to the PLC over Modbus TCP.

Every cycle at write_rate_hz, while the link is up, the node writes the latest command clamped
to min(p_max_kpa, the register map's p_max_kpa), or zeros (vent) when no valid command arrived
within command_timeout_s or the latest one was invalid; then it bumps the heartbeat the PLC's
watchdog watches, reads the measured pressures back and publishes them. A lost link is retried
with an exponential backoff, and the latest fresh command is written again once it is back.
On SIGINT/SIGTERM `run()` calls `safe_shutdown()`, which vents every channel before exiting.

A stop from any connection (plc_stop.py): kept out of a PLC by another client's write claim for
two plc_watchdog_s, the node writes the PLC's vent request and reports ERROR with the
other client's address; a PLC's vent latch seen set (by anyone) calls the controller's vent; the
latch is released only for a command with pressure that the controller sent after that vent was
answered (so after the operator's enable).

A lifecycle node (docs/lifecycle.md): configure reads the maps and connects; only while active
are commands written; inactive writes zeros with the heartbeat (the link held, the suit vented);
cleanup, shutdown and error processing vent every PLC, confirm it and close the links.

Several PLCs (a register map with `endpoints`): each serves some channels and has its own
link. Commands are written only while every link is up; a fault on any link vents all the
others at once, and each link is retried on its own backoff with a vent, a heartbeat and a
read (never the command) until it passes; then commands flow again. /diagnostics has one
status per link besides the overall one: a link is "down" (no connection), "refused" (the
PLC answers with a Modbus exception: the register map or the PLC program is wrong, or, with
exception 06, another client holds the PLC's write claim: one writer at a time) or
"no answer" (silence on an open connection: check the unit id).
With write_on_command (the default) each command is also written the moment it arrives, so it
does not wait for the next cycle; the cycle keeps the heartbeat, the re-send and the read-back.

Only the controller of the running graph moves a register (nodes/command_source.py): a command
from any publisher but `command_publisher`'s (a bag played back, a second node) is refused and
counted; a command is aged from its source timestamp (when it was sent), so one that outlived a
frozen process is stale on arrival; a command whose layout label does not name the configured
channel order is invalid (vent).

Subscribes: pressure_command (std_msgs/Float64MultiArray, kPa, channel order)
Publishes:  measured_pressure (std_msgs/Float64MultiArray, kPa, channel order; while configured),
            /diagnostics (with the lifecycle state)
Services:   the lifecycle services (~/change_state, ~/get_state, ...)
"""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rclpy.clock import Clock, ClockType
from std_msgs.msg import Float64MultiArray

from fabric_guidance.core.channels import ChannelMap, layout_label
from fabric_guidance.core.feedback import PAPER_P_MAX
from fabric_guidance.interface import DIAGNOSTICS, MEASURED_PRESSURE, PRESSURE_COMMAND
from fabric_guidance.nodes.array_layout import named_layout
from fabric_guidance.nodes.command_source import CommandSource, Publisher, full_name, sent_age_s
from fabric_guidance.nodes.diagnostics import publish_diagnostics, status
from fabric_guidance.nodes.log_throttle import LogThrottle
from fabric_guidance.nodes.managed import ManagedNode
from fabric_guidance.nodes.parameters import declare, declare_config_file
from fabric_guidance.nodes.plc_stop import KEPT_OUT_WATCHDOGS, KeptOut, StopRelay, VentLatch
from fabric_guidance.nodes.qos import COMMAND_QOS
from fabric_guidance.nodes.spin import run
from fabric_guidance.paths import resolve
from fabric_guidance.plc import PlcClient, PlcEndpoint, PlcLayout, PlcLinkError, PlcRefusedError
from fabric_guidance.plc.pymodbus_compat import PYMODBUS_VERSION

#: Errors about bad commands or an unreachable PLC are logged at most this often [s].
LOG_THROTTLE_S = 1.0
UP = 'up'


class _Link:
    """One PLC endpoint: its client, its channels' places in the command vector, its state."""

    def __init__(self, endpoint: PlcEndpoint, client: PlcClient, reconnect_min_s: float):
        self.name, self.client, self.indices = endpoint.name, client, list(endpoint.indices)
        self.state = 'down'          # UP, or PlcLinkError.state: 'down', 'refused', 'no answer'
        self.last_error = 'not connected yet'
        self.backoff_s = reconnect_min_s
        self.next_attempt_s = time.monotonic()
        self.ever_up = False
        self.failures = self.reconnects = 0
        self.last_round_trip_s: float | None = None
        self.kept_out = KeptOut()    # another client's claim, the PLC's vent latch (plc_stop.py)

    @property
    def up(self) -> bool:
        return self.state == UP


class PlcOutput(ManagedNode, VentLatch):
    """The PLC driver as a lifecycle node (nodes/managed.py): configure reads the maps and
    connects; active writes commands; inactive writes zeros and the heartbeat (the link is held,
    the suit vented); cleanup, shutdown and error vent every PLC and close the links."""

    def __init__(self):
        super().__init__('plc_output')
        # Every parameter is read once, here; read-only so that `ros2 param set` cannot appear
        # to change a value (a pressure limit above all) that the running node does not use.
        self.plc_host = declare(self, 'plc_host', '127.0.0.1',
                                "the PLC's address (Modbus TCP); a register map with endpoints "
                                'names its own',
                                read_only=True)
        self.plc_port = declare(self, 'plc_port', 1502,
                                "the PLC's Modbus TCP port; a register map with endpoints names "
                                'its own',
                                '', 1, 65535, read_only=True)
        self.register_map_file = declare_config_file(self, 'register_map_file', 'hardware/plc_register_map.yaml',
                                                     'register map')
        self.channel_map_file = declare_config_file(self, 'channel_map_file', 'hardware/channel_map.yaml',
                                                    'channel map')
        self.p_max_param = declare(self, 'p_max_kpa', PAPER_P_MAX,
                                   'commands are clamped to this (and to the register map p_max_kpa) before writing',
                                   'kPa', 0.0, 1000.0, read_only=True)
        self.write_rate_hz = declare(self, 'write_rate_hz', 50.0, 'commands and heartbeat written per second',
                                     'Hz', 1.0, 1000.0, read_only=True)
        self.command_timeout_s = declare(self, 'command_timeout_s', 0.5,
                                         'vent when no valid command arrived for this long', 's', 0.01, 60.0,
                                         read_only=True)
        self.modbus_timeout_s = declare(self, 'modbus_timeout_s', 0.2, 'timeout of one Modbus request or connection',
                                        's', 0.01, 10.0, read_only=True)
        self.reconnect_min_s = declare(self, 'reconnect_min_s', 0.2,
                                       'wait after a lost link, doubling up to reconnect_max_s', 's', 0.01, 600.0,
                                       read_only=True)
        self.reconnect_max_s = declare(self, 'reconnect_max_s', 5.0, 'longest wait between reconnection attempts',
                                       's', 0.01, 600.0, read_only=True)
        self.write_on_command = declare(self, 'write_on_command', True,
                                        'also write each command as soon as it arrives', read_only=True)
        self.command_publisher = declare(self, 'command_publisher', 'pressure_controller',
                                         'the node (name, relative to this namespace) whose pressure_command '
                                         'is written; commands of every other publisher are refused',
                                         read_only=True)
        if not self.command_publisher:
            raise ValueError('parameter "command_publisher" must name a node, got an empty string')
        self.plc_watchdog_s = declare(self, 'plc_watchdog_s', 0.5,
                                      "the PLC's watchdog time: refused as busy (another client's "
                                      'write claim) for twice as long, the node writes the vent request',
                                      's', 0.05, 60.0, read_only=True)
        diagnostics_period_s = declare(self, 'diagnostics_period_s', 1.0, '/diagnostics publication period',
                                       's', 0.05, 60.0, read_only=True)
        if self.reconnect_min_s > self.reconnect_max_s:
            raise ValueError(f'parameter "reconnect_min_s" ({self.reconnect_min_s} s) must not exceed '
                             f'"reconnect_max_s" ({self.reconnect_max_s} s)')
        self._links: list[_Link] = []
        self.n = 0
        self.plc_address = ''
        self.p_max_kpa = 0.0
        self._write_timer = self._command_sub = None
        self._heartbeat = 0
        self._writes = self._invalid_commands = self._ignored_commands = 0
        self._commands_received = 0   # pressure_commands delivered that are not a vent, before any check
        self._source: CommandSource | None = None
        self._refused_reported = 0
        self._command_label = ''
        # A stop of the whole system (plc_stop.py): the controller's vent, called when a PLC's
        # vent latch is seen; the re-arm waits for its next command with pressure after that.
        self._relay = StopRelay(time.time)
        self._controller_vent = None
        # Per-command warnings (a controller gone wrong sends one per message): decided before rclpy.
        self._log_throttle = LogThrottle(LOG_THROTTLE_S)
        self._forget_command()
        self._measured_pub = self.create_publisher(Float64MultiArray, MEASURED_PRESSURE, COMMAND_QOS)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        # Steady clock: writing, heartbeat and venting never wait for a simulated /clock.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        # Diagnostics in every state, the lifecycle state among them.
        self._diagnostics_timer = self.create_timer(diagnostics_period_s, self._on_diagnostics_timer,
                                                    clock=self._steady)

    def _forget_command(self) -> None:
        self._zeros = np.zeros(self.n)
        self._command = self._zeros        # latest valid command, already clamped [kPa]
        self._command_s: float | None = None  # time.monotonic() of its arrival
        self._command_sent_wall: float | None = None  # its source timestamp [s, wall clock]
        self._invalid = False              # the latest message was invalid: vent until a valid one
        self._invalid_why = ''
        self._vent_reason = ''

    # --------------------------------------------------------------- lifecycle
    def configure(self) -> None:
        channel_path = resolve(self.channel_map_file, 'hardware/channel_map.yaml')
        channel_map = ChannelMap.load(channel_path)
        self.layout = PlcLayout.load(resolve(self.register_map_file, 'hardware/plc_register_map.yaml'),
                                     expected_channels=channel_map.channels)
        # The channel order, read-only like ros2_controllers' `joints`: it comes from the channel
        # map (declared at the first configure; a later configure must find the same order).
        if self.has_parameter('channels'):
            channels = self.get_parameter('channels').value
        else:
            channels = declare(self, 'channels', list(channel_map.channels),
                               'channel order of pressure_command and measured_pressure (from channel_map_file)',
                               read_only=True)
        if list(channels) != list(channel_map.channels):
            raise ValueError(f'parameter "channels" {list(channels)} does not match the channel order of '
                             f'{channel_path}: {list(channel_map.channels)}')
        self.p_max_kpa = min(self.p_max_param, self.layout.p_max_kpa)
        self.n = len(self.layout)
        self._links = []
        for e in self.layout.endpoints:
            host, port = (self.plc_host, self.plc_port) if e.host is None else (e.host, e.port)
            self._links.append(_Link(e, PlcClient(e.map, host, port, timeout_s=self.modbus_timeout_s),
                                     self.reconnect_min_s))
        self.plc_address = ', '.join(link.client.address for link in self._links)
        self._forget_command()
        self._measured_layout = named_layout(channel_map.channels)
        self._command_label = layout_label(channel_map.channels)
        self._command_sub = self.create_subscription(Float64MultiArray, PRESSURE_COMMAND, self._on_command,
                                                     COMMAND_QOS)
        if self._controller_vent is None:
            self._controller_vent = self.vent_client(full_name(self.command_publisher, self.get_namespace()))
        if self._source is None:   # kept over a cleanup and configure: its counts are the node's
            topic = self._command_sub.topic_name   # as resolved (namespace, remaps)
            self._source = CommandSource(
                full_name(self.command_publisher, self.get_namespace()),
                lambda: [Publisher(e.node_name, e.node_namespace, bytes(e.endpoint_gid))
                         for e in self.get_publishers_info_by_topic(topic)])
        self._write_timer = self.create_timer(1.0 / self.write_rate_hz, self._on_write_timer, clock=self._steady)
        self.get_logger().info(
            f'writing {self.n} channels {list(channel_map.channels)} to the PLC at {self.plc_address} '
            f'at {self.write_rate_hz:g} Hz, p_max {self.p_max_kpa:g} kPa (parameter {self.p_max_param:g}, '
            f'register map {self.layout.p_max_kpa:g}), command timeout {self.command_timeout_s:g} s, '
            f'pymodbus {PYMODBUS_VERSION}')
        if len(self._links) > 1 or self.layout.endpoints[0].host is not None:
            listed = '; '.join(f'{link.name} at {link.client.address} unit id '
                               f'{link.client.map.unit_id}: {list(link.client.map.names)}'
                               for link in self._links)
            self.get_logger().info(f'PLC endpoints from the register map (plc_host and plc_port '
                                   f'unused): {listed}')
        # Connect now (vent, heartbeat, read); a PLC that is not there yet is retried on the
        # backoff by the write cycle, as a link lost later is.
        for link in self._links:
            self._retry(link)

    def activate(self) -> None:
        # Only commands that arrive from now on are written: nothing heard while inactive.
        self._forget_command()

    def deactivate(self) -> None:
        self._forget_command()
        if self._all_up():
            self._write_now()            # zeros: the node is no longer active

    def release(self) -> None:
        if self._write_timer is not None:
            self.destroy_timer(self._write_timer)
            self._write_timer = None
        if self._command_sub is not None:
            self.destroy_subscription(self._command_sub)
            self._command_sub = None
        for link in self._links:
            self._vent_on_shutdown(link)
        self._links = []

    # ---------------------------------------------------------------- commands
    def _on_command(self, msg: Float64MultiArray, info) -> None:
        self._commands_received += any(msg.data)
        if not self.active:
            self._ignored_commands += 1
            return
        # Whose command: only the controller's moves a register; any other is dropped without
        # touching the controller's latest (a second publisher cannot vent the suit either).
        refused = self._source.check(info)
        # How old: from when it was sent (the publisher's clock at publish), so a command that
        # waited in a frozen process or in DDS is as old as it is, not as old as its delivery.
        age_s = sent_age_s(info)
        if not refused and age_s is None:
            refused = self._source.refuse('no source time', 'without a source timestamp (its age is unknown)')
        if refused:
            if self._log_throttle.due('refused'):
                self.get_logger().warning(f'refusing pressure_command {refused}: only '
                                          f'{self._source.node} moves the registers')
            return
        p = np.asarray(msg.data, dtype=float)
        label = msg.layout.dim[0].label if msg.layout.dim else ''
        why = ''
        if age_s < 0.0:
            # Sent "in the future": a clock stepped back (or the sender's is ahead); its age is
            # unknown, so it is not counted fresh.
            why = f'sent {-age_s:.3f} s in the future by its source timestamp (a clock stepped back)'
        elif label != self._command_label:
            why = f'channels "{label}", configured "{self._command_label}"'
        elif p.shape != (self.n,):
            why = f'{p.size} values, need {self.n}'
        elif not np.all(np.isfinite(p)):
            why = f'non-finite values on channels {[int(i) for i in np.flatnonzero(~np.isfinite(p))]}'
        if why:
            self._invalid_commands += 1
            self._invalid, self._invalid_why, self._command = True, why, self._zeros
            if self._log_throttle.due('invalid'):
                self.get_logger().error(f'invalid pressure_command ({why}): venting all channels')
            if self.write_on_command and self._all_up():
                self._write_now()
            return
        if np.any(p > self.p_max_kpa) and self._log_throttle.due('above p_max'):
            self.get_logger().warning(f'pressure_command above p_max ({p.max():g} kPa): clamped to '
                                      f'{self.p_max_kpa:g} kPa')
        self._invalid = False
        self._command = np.clip(p, 0.0, self.p_max_kpa)
        self._command_s = time.monotonic() - age_s
        self._command_sent_wall = time.time() - age_s
        if self.write_on_command and self._all_up():
            self._write_now()

    def _all_up(self) -> bool:
        return all(link.up for link in self._links)

    def _write_now(self) -> None:
        """Write what the cycle would write (the latest command, or zeros) at once."""
        target = self._target(time.monotonic())[0]
        for link in self._links:
            try:
                self._maybe_rearm(link, target)
                link.client.write_pressures(target[link.indices])
            except PlcLinkError as exc:
                self._link_lost(link, exc)
                return

    def _target(self, now_s: float) -> tuple[np.ndarray, str]:
        """What to write now, and why it is zeros ('' when it is the command)."""
        if not self.active:
            return self._zeros, f'{self.state_label} (lifecycle)'
        if self._invalid:
            return self._zeros, 'invalid command'
        if self._command_s is None:
            return self._zeros, 'no command received yet'
        if now_s - self._command_s > self.command_timeout_s:
            return self._zeros, f'stale command (none for {self.command_timeout_s:g} s)'
        return self._command, ''

    # ------------------------------------------------------------------- cycle
    def _on_write_timer(self) -> None:
        self._tell_controller()
        now = time.monotonic()
        healthy = self._all_up()
        target, reason = self._target(now)
        if not healthy:
            target, reason = self._zeros, 'a PLC link is not up'
        if reason != self._vent_reason:
            if reason:
                self.get_logger().warning(f'venting all channels: {reason}')
            else:
                self.get_logger().info('writing commands')
            self._vent_reason = reason
        measured = np.zeros(self.n)
        complete = True
        for link in self._links:
            if not link.up:
                complete = False
                # A retry is this cycle's only blocking call for the link (at most one timeout).
                if now >= link.next_attempt_s:
                    self._retry(link)
                continue
            try:
                # The first failing request ends the link's cycle: one timeout at most.
                self._maybe_rearm(link, target)
                link.last_round_trip_s = link.client.write_pressures(target[link.indices])
                link.client.write_heartbeat(self._heartbeat + 1)
                measured[link.indices] = link.client.read_measured_kpa()
                self._read_latch(link)
            except PlcLinkError as exc:
                self._link_lost(link, exc)
                return
            link.backoff_s = self.reconnect_min_s  # a whole cycle went through: the link is good
        self._heartbeat += 1
        if complete:
            self._writes += 1
            self._measured_pub.publish(Float64MultiArray(layout=self._measured_layout,
                                                         data=[float(v) for v in measured]))

    def _retry(self, link: _Link) -> None:
        """Reconnect and prove the link with a vent, a heartbeat and a read (never the command)."""
        if link.state == 'down':
            link.client.close()  # always a fresh socket after a broken connection
            if not link.client.connect():
                link.last_error = f'cannot connect to {link.client.address}'
                self._schedule_retry(link)
                self.get_logger().error(f'PLC {link.name} at {link.client.address} unreachable; '
                                        f'next attempt in '
                                        f'{link.next_attempt_s - time.monotonic():.1f} s',
                                        throttle_duration_sec=LOG_THROTTLE_S)
                return
        try:
            link.client.vent()
            link.client.write_heartbeat(self._heartbeat + 1)
            link.client.read_measured_kpa()
        except PlcLinkError as exc:
            self._link_lost(link, exc)
            if link.kept_out.overdue(time.monotonic(), self.plc_watchdog_s):
                self._request_vent(link)
            return
        link.kept_out.up()
        if link.ever_up:
            link.reconnects += 1
        link.ever_up = True
        link.state, link.backoff_s = UP, self.reconnect_min_s
        self.get_logger().info(f'PLC {link.name} at {link.client.address} up')

    def _link_lost(self, link: _Link, exc: PlcLinkError) -> None:
        """A link failed: vent every other link now, retry this one on its backoff."""
        was = link.state
        link.state, link.last_error = exc.state, str(exc)
        link.kept_out.refused(isinstance(exc, PlcRefusedError) and exc.code == 6, time.monotonic())
        if was == UP:
            link.failures += 1
        if exc.state == 'down':
            link.client.close()
        self._schedule_retry(link)
        what = {'down': 'link lost', 'refused': 'refuses',
                'no answer': 'does not answer'}[exc.state]
        self.get_logger().error(f'PLC {link.name} {what}: {exc}; venting all PLCs, retrying '
                                '(the PLC watchdog vents meanwhile)',
                                throttle_duration_sec=LOG_THROTTLE_S)
        for other in self._links:
            if other is not link and other.up:
                try:
                    other.client.vent()
                except PlcLinkError as other_exc:
                    self._link_lost(other, other_exc)

    def _schedule_retry(self, link: _Link) -> None:
        link.next_attempt_s = time.monotonic() + link.backoff_s
        link.backoff_s = min(2.0 * link.backoff_s, self.reconnect_max_s)
        since = link.kept_out.since
        if since is not None and not link.kept_out.requested:
            # Kept out: try again when the watchdog's time is up, not a backoff later.
            link.next_attempt_s = min(link.next_attempt_s, since + KEPT_OUT_WATCHDOGS * self.plc_watchdog_s)

    # ------------------------------------------------------------- diagnostics
    def _on_diagnostics_timer(self) -> None:
        _, reason = self._target(time.monotonic())
        if reason == 'invalid command':   # with its reason here (the cycle's log line stays one per change)
            reason = f'invalid command ({self._invalid_why})'
        faulty = [link for link in self._links if not link.up]
        if faulty:
            level = DiagnosticStatus.ERROR
            message = '; '.join(self._link_message(link) for link in faulty)
            if len(self._links) > 1:
                message = f'venting all PLCs: {message}'
        elif any(link.kept_out.latched for link in self._links):
            latched = [link.name for link in self._links if link.kept_out.latched]
            level, message = DiagnosticStatus.WARN, (
                f'vent latch set on PLC {", ".join(latched)}: vented until the operator enables')
        elif reason:
            level, message = DiagnosticStatus.WARN, f'venting: {reason}'
        else:
            level, message = DiagnosticStatus.OK, 'writing commands'
        refused = self._source.refused if self._source is not None else 0
        if refused > self._refused_reported and level == DiagnosticStatus.OK:
            # Refused commands since the last report: someone else publishes pressure_command.
            level, message = DiagnosticStatus.WARN, f'refusing pressure_command {self._source.last_refusal}'
        self._refused_reported = refused
        if self.configure_error:
            level, message = DiagnosticStatus.ERROR, f'unconfigured: {self.configure_error}'
        age = 'never' if self._command_s is None else f'{time.monotonic() - self._command_s:.3f}'
        rtts = [link.last_round_trip_s for link in self._links
                if link.last_round_trip_s is not None]
        rtt = 'none' if not rtts else f'{1e3 * max(rtts):.2f}'
        values = {'connected': not faulty, 'last round trip ms': rtt, 'writes': self._writes,
                  'link failures': sum(link.failures for link in self._links),
                  'reconnects': sum(link.reconnects for link in self._links),
                  'invalid commands': self._invalid_commands, 'command age s': age,
                  'plc address': self.plc_address, 'p_max kPa': f'{self.p_max_kpa:g}',
                  'commands received (not a vent)': self._commands_received,
                  'commands ignored while not active': self._ignored_commands,
                  'commands refused (not the controller\'s)': refused,
                  'refused by publisher': ' '.join(f'{k}={v}' for k, v in sorted(
                      (self._source.refused_by if self._source is not None else {}).items())) or 'none',
                  'last refusal': self._source.last_refusal if self._source is not None and refused else '',
                  'vent latched': ' '.join(link.name for link in self._links if link.kept_out.latched) or 'none',
                  'vent requests written': sum(link.kept_out.vent_requests for link in self._links),
                  'controller vent calls': f'{self._relay.calls} ({self._relay.failures} failed)',
                  **self.lifecycle_values()}
        statuses = [status(self, 'PLC output', level, message, values, hardware_id=f'PLC {self.plc_address}')]
        for link in self._links:
            link_level = DiagnosticStatus.OK if link.up else DiagnosticStatus.ERROR
            statuses.append(status(self, f'PLC link {link.name}', link_level,
                                   'up' if link.up else self._link_message(link),
                                   {'state': link.state, 'address': link.client.address,
                                    'unit id': link.client.map.unit_id,
                                    'channels': ' '.join(link.client.map.names),
                                    'link failures': link.failures,
                                    'reconnects': link.reconnects,
                                    'claim holder': link.kept_out.holder or 'unknown',
                                    'vent latched': link.kept_out.latched},
                                   hardware_id=f'PLC {link.client.address}'))
        publish_diagnostics(self, self._diagnostics_pub, statuses)

    @staticmethod
    def _link_message(link: _Link) -> str:
        # "down" only for a link that is: a PLC that answers but refuses, or a unit id that
        # gets no answer, is a configuration fault with its own words.
        if link.state == 'refused' and link.kept_out.since is not None:
            return (f'PLC {link.name} {link.kept_out.describe(time.monotonic())}; commands not '
                    f'written: {link.last_error}')
        if link.state == 'refused':
            return f'PLC {link.name} refuses (link up, commands not written): {link.last_error}'
        if link.state == 'no answer':
            return (f'PLC {link.name} does not answer its unit id (commands not written): '
                    f'{link.last_error}')
        return f'PLC link down ({link.name}): {link.last_error}'

    # ---------------------------------------------------------------- shutdown
    def safe_shutdown(self) -> None:
        """Vent every channel of every PLC and confirm it by reading the command registers back."""
        self.active = False
        self._diagnostics_timer.cancel()
        if self._write_timer is not None:
            self._write_timer.cancel()
        for link in self._links:
            self._vent_on_shutdown(link)

    def _vent_on_shutdown(self, link: _Link) -> None:
        log, client = self.get_logger(), link.client
        error = None
        # Two tries: the second on a fresh connection, in case the signal cut a request short.
        for attempt in range(2):
            try:
                if attempt > 0 or link.state == 'down':
                    client.close()
                    if not client.connect():
                        error = f'cannot connect to {client.address}'
                        break  # one quick attempt only: do not hold the shutdown up
                round_trip_s = client.vent()
                left = client.read_commands_kpa()
            except PlcLinkError as exc:
                error = str(exc)
                continue
            if not np.any(left):
                log.info(f'vented all {len(client.map)} channels of PLC {link.name} on shutdown '
                         f'(round trip {1e3 * round_trip_s:.1f} ms)')
                error = None
                break
            error = f'command registers read back {list(left)} after venting'
        if error is not None:
            log.error(f'could not vent PLC {link.name} on shutdown: {error}; its watchdog vents '
                      'once the heartbeat stops')
        client.close()


def main(args=None):
    # rclpy's SingleThreadedExecutor, not the events executor: this node blocks in its callbacks
    # (Modbus requests), and behind a slow link the events executor starved the diagnostics
    # timer (test_faults_link's slow-link test); the single-threaded one serves every timer.
    return run(lambda: PlcOutput(), args, executor='single')


if __name__ == '__main__':
    sys.exit(main())
