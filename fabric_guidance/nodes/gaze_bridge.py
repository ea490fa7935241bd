"""gaze_bridge: the HoloLens gaze stream (UDP, docs/gaze_wire_format.md) into ROS.

A receiver thread blocks on the UDP socket and, for every datagram, in this order:
drops it when the sender is not in allowed_senders ('sender'); drops it when it waited in the
PC's receive buffer longer than max_queue_delay_s ('late': after the thread was held up, or a
flood, the backlog is old gaze that would otherwise pass for fresh and keep the suit guiding
after the stream stopped; the kernel's arrival time says how long it waited); parses it with
core.gaze_wire.parse_datagram, dropping it under the WireFormatError's reason; tracks its
sequence number, dropping duplicates and reordered samples ('stale'); drops it when the
HoloLens marks eye tracking as not valid and require_eye_tracking_valid is set
('eye_tracking_invalid'); otherwise publishes it on `gaze` and, when something subscribes
to it, `head_pose`.

The sequence number is tracked before the eye-tracking check so that samples the bridge
drops on purpose are not counted as lost on the network.

The headset's clock (docs/headset_wire_format.md): with headset_address set, the bridge sends
a clock_ping every clock_ping_period_s from its own socket to headset_address:display_port and
feeds the clock_echo answers to core.clock_sync.ClockEstimator. Once that has an estimate,
`gaze` and `head_pose` carry the capture time (the datagram's `stamp` on the bridge's clock,
mapped to ROS time) instead of the receive time, and /diagnostics reports the one-way delay
from capture to receipt. A headset clock that runs backwards, a sender restart or a capture
time that cannot be (in the future, or older than MAX_DELAY_S) restarts the estimate or falls
back to the receive time for that sample, and so does an estimate carried on without clock echoes
for longer than its drift allows (core.clock_sync.MAX_CARRIED_S: a headset that stopped answering
pings, most quickly one whose estimate was still settling): nothing is published with a stamp it
cannot stand by.

A `confirm` datagram (the wearer's clicker or air tap) is published once per press on `confirm`
(std_msgs/Header): the headset sends each press three times with one press_id, and the bridge
keeps the last CONFIRM_MEMORY (press_id, stamp) pairs to publish each once. Its stamp is the
press's capture time converted exactly as a gaze sample's is, frame_id CONFIRM_SOURCE.

Publishing happens on the receiver thread (rclpy publishers are thread-safe), so the rate
does not depend on the executor; nothing is logged per sample. /diagnostics reports the
counters every diagnostics_period_s.

Published:  gaze (geometry_msgs/PoseStamped, x axis along the gaze ray), head_pose
            (geometry_msgs/PoseStamped), confirm (std_msgs/Header), /diagnostics (diagnostic_msgs/DiagnosticArray).
"""
from __future__ import annotations

from collections import deque
import ipaddress
import socket
import struct
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from std_msgs.msg import Header

from rclpy.duration import Duration

from fabric_guidance.core.clock_sync import (MAX_CARRIED_S, ClockEcho, ClockEstimator, capture_delay, encode_ping,
                                             parse_uplink)
from fabric_guidance.core.gaze_wire import REASONS, Confirm, SeqStatus, SequenceTracker, WireFormatError
from fabric_guidance.core.geometry import GeometryError, ray_orientation
from fabric_guidance.interface import CONFIRM, DIAGNOSTICS, GAZE, HEAD_POSE, IMMERSIVE_FRAME
from fabric_guidance.nodes.diagnostics import publish_diagnostics, status
from fabric_guidance.nodes.parameters import declare
from fabric_guidance.nodes.qos import EVENT_QOS, SENSOR_QOS
from fabric_guidance.nodes.spin import run

#: Receive buffer asked for (the kernel caps it at net.core.rmem_max): ~10 s of samples at 90 Hz
#: would fit in far less, but a burst must not be lost while the thread is descheduled.
RECEIVE_BUFFER_BYTES = 4 * 1024 * 1024
#: recvfrom timeout: how long safe_shutdown waits for the thread at most.
RECEIVE_TIMEOUT_S = 0.1
#: Loss rate (sequence gaps over the last period) above which the stream is reported WARN.
MAX_LOSS_RATE = 0.05
#: A capture this much older than its receipt is not believed: the stamp falls back to receipt [s].
MAX_DELAY_S = 1.0
#: One-way delays kept for the diagnostics percentiles (more than a period at 1 kHz).
DELAY_BUFFER = 4096
#: Drop reasons of the bridge besides WireFormatError.reason.
BRIDGE_REASONS: tuple[str, ...] = ('sender', 'late', 'stale', 'eye_tracking_invalid', 'internal')
#: Linux's SO_TIMESTAMPNS (Python has no name for it): each datagram carries its arrival time
#: (CLOCK_REALTIME, struct timespec) as ancillary data.
SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct('@qq')
#: frame_id of a confirm press from the headset (the study's other sources name themselves).
CONFIRM_SOURCE = 'headset'
#: Presses remembered to publish each once (a press is sent three times, 20 ms apart).
CONFIRM_MEMORY = 64


class GazeBridge(Node):

    def __init__(self):
        super().__init__('gaze_bridge')
        self.bind_address = declare(self, 'bind_address', '127.0.0.1',
                                    'UDP address to listen on', read_only=True)
        self.port = declare(self, 'port', 5005, 'UDP port to listen on', '-', 1, 65535, read_only=True)
        allowed = declare(self, 'allowed_senders', ['127.0.0.1'],
                          'sender IP addresses accepted; datagrams from others are dropped', read_only=True)
        self.max_datagram_bytes = declare(self, 'max_datagram_bytes', 1024,
                                          'larger datagrams are dropped unread', 'bytes', 64, 65507,
                                          read_only=True)
        self.require_valid = declare(self, 'require_eye_tracking_valid', True,
                                     'drop samples the HoloLens marks as not valid', read_only=True)
        self.frame_id = declare(self, 'frame_id', IMMERSIVE_FRAME,
                                'frame of the published poses (the immersive space)', read_only=True)
        self.period = declare(self, 'diagnostics_period_s', 1.0, 'diagnostics period', 's', 0.05, 60.0,
                              read_only=True)
        self.headset_address = declare(self, 'headset_address', '',
                                       "the HoloLens's IP address, where clock pings go ('' = no clock "
                                       'exchange: gaze is stamped on receipt)', read_only=True)
        self.display_port = declare(self, 'display_port', 5006, "the headset's downlink UDP port (pings)",
                                    '-', 1, 65535, read_only=True)
        ping_period = declare(self, 'clock_ping_period_s', 0.2, 'time between clock pings', 's', 0.01, 10.0,
                              read_only=True)
        window = declare(self, 'clock_window_s', 30.0, 'clock exchanges the offset and drift are fitted over',
                         's', 1.0, 600.0, read_only=True)
        self.max_queue_delay_s = declare(self, 'max_queue_delay_s', 0.2,
                                         "drop a datagram that waited longer than this in the PC's receive "
                                         'buffer (a backlog is old gaze); 0 = never', 's', 0.0, 10.0,
                                         read_only=True)
        self.stamp_source = declare(self, 'stamp_source', 'capture',
                                    "'capture': the headset's capture time once the clock is estimated, "
                                    "receipt until then; 'receipt': always the receive time", read_only=True)
        if self.stamp_source not in ('capture', 'receipt'):
            raise ValueError(f"parameter 'stamp_source': {self.stamp_source!r} is not 'capture' or 'receipt'")

        try:
            family = socket.AF_INET6 if ipaddress.ip_address(self.bind_address).version == 6 else socket.AF_INET
        except ValueError:
            raise ValueError(f"parameter 'bind_address': {self.bind_address!r} is not an IP address") from None
        self.allowed_senders = self._parse_senders(allowed)
        self._ping_target = None
        if self.headset_address:
            try:
                headset = ipaddress.ip_address(self.headset_address)
            except ValueError:
                raise ValueError(f"parameter 'headset_address': {self.headset_address!r} is not an IP "
                                 'address') from None
            if family == socket.AF_INET6 and headset.version == 4:
                headset = ipaddress.ip_address(f'::ffff:{headset}')
            elif family == socket.AF_INET and headset.version == 6:
                raise ValueError(f"parameter 'headset_address': {headset} is IPv6 but 'bind_address' "
                                 f'{self.bind_address} is IPv4')
            self._ping_target = (str(headset), self.display_port)
        if not self.allowed_senders:
            self.get_logger().warn("parameter 'allowed_senders' is empty: every datagram will be dropped")

        self._lock = threading.Lock()  # guards the counters below (receiver thread and timer)
        self._dropped = {reason: 0 for reason in REASONS + BRIDGE_REASONS}
        self._received = 0
        self._published = 0
        self._tracker = SequenceTracker()
        self._last = (0, 0, 0, 0, time.monotonic())  # received, published, seq received, seq lost, when
        self._headset_clock = ClockEstimator(window_s=window)
        self._ping_seq = 0
        self._echoes = 0
        self._delays: list[float] = []      # one-way delays of this period [s], at most DELAY_BUFFER
        self._stamp_fallbacks = 0           # captures not believed: stamped on receipt
        self._captured = 0                  # published with the capture time
        self._confirm_seen: deque = deque(maxlen=CONFIRM_MEMORY)   # (press_id, stamp) published
        self._confirms = 0                  # presses published
        self._confirm_repeats = 0           # repeats of a press already published

        self._gaze_pub = self.create_publisher(PoseStamped, GAZE, SENSOR_QOS)
        self._head_pub = self.create_publisher(PoseStamped, HEAD_POSE, SENSOR_QOS)
        self._confirm_pub = self.create_publisher(Header, CONFIRM, EVENT_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)

        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
            self._sock.bind((self.bind_address, self.port))
            self._sock.settimeout(RECEIVE_TIMEOUT_S)
            try:
                self._sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self._arrival_times = True
            except OSError:   # not Linux: no arrival times, no datagram is judged late
                self._arrival_times = False
        except OSError as exc:
            self._sock.close()
            raise OSError(f'cannot listen on {self.bind_address}:{self.port} '
                          f"(parameters 'bind_address', 'port'): {exc}") from None
        self.receive_buffer_bytes = self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)

        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive_loop, name='gaze_bridge_udp', daemon=True)
        self._thread.start()
        self._timer = self.create_timer(self.period, self._publish_diagnostics)
        if self._ping_target is not None:
            self._ping_timer = self.create_timer(ping_period, self._ping)
        self.get_logger().info(
            f'listening on {self.bind_address}:{self.port} (receive buffer {self.receive_buffer_bytes} bytes), '
            f'accepting {sorted(self.allowed_senders)}, publishing {GAZE} and {HEAD_POSE} in {self.frame_id!r}; '
            + (f'clock pings to {self._ping_target[0]}:{self._ping_target[1]} every {ping_period} s'
               if self._ping_target else "no clock exchange ('headset_address' empty): stamped on receipt"))

    @staticmethod
    def _parse_senders(values) -> frozenset[str]:
        senders = set()
        for value in values or []:
            if value == '':
                continue
            try:
                ip = ipaddress.ip_address(value)
            except ValueError:
                raise ValueError(f"parameter 'allowed_senders': {value!r} is not an IP address") from None
            # An IPv6 socket reports an IPv4 sender as ::ffff:a.b.c.d and the receive loop strips
            # that prefix: an allowed sender written either way is the IPv4 address.
            mapped = getattr(ip, 'ipv4_mapped', None)
            senders.add(str(mapped if mapped is not None else ip))
        return frozenset(senders)

    # --- receiver thread ------------------------------------------------------------------

    def _receive_loop(self) -> None:
        sock, stop = self._sock, self._stop
        bufsize = self.max_datagram_bytes + 1  # a longer datagram arrives truncated to this: 'oversize'
        mapped = sock.family == socket.AF_INET6  # an IPv6 socket reports IPv4 senders as ::ffff:a.b.c.d
        ancillary = socket.CMSG_SPACE(_TIMESPEC.size) if self._arrival_times else 0
        while not stop.is_set():
            try:
                data, cmsgs, _flags, address = sock.recvmsg(bufsize, ancillary)
            except socket.timeout:
                continue
            except OSError as exc:
                if stop.is_set():
                    break
                self.get_logger().error(f'UDP receive failed: {exc}', throttle_duration_sec=5.0)
                stop.wait(RECEIVE_TIMEOUT_S)
                continue
            sender = address[0]
            if mapped and sender.startswith('::ffff:'):
                sender = sender[7:]
            waited_s = 0.0
            for level, kind, cdata in cmsgs:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(cdata) >= _TIMESPEC.size:
                    sec, nsec = _TIMESPEC.unpack_from(cdata)
                    waited_s = time.time() - (sec + nsec * 1e-9)
            try:
                self._handle(data, sender, waited_s)
            except Exception as exc:  # noqa: BLE001 - the stream must survive anything
                with self._lock:
                    self._dropped['internal'] += 1
                self.get_logger().error(f'datagram dropped by an internal error: {exc!r}',
                                        throttle_duration_sec=5.0)

    def _handle(self, data: bytes, sender: str, waited_s: float = 0.0) -> None:
        received_mono = time.monotonic()
        now = self.get_clock().now()
        lock, dropped = self._lock, self._dropped
        if sender not in self.allowed_senders:
            with lock:
                self._received += 1
                dropped['sender'] += 1
            return
        if self.max_queue_delay_s and waited_s > self.max_queue_delay_s:
            with lock:
                self._received += 1
                dropped['late'] += 1
            return
        try:
            sample = parse_uplink(data, self.max_datagram_bytes)
        except WireFormatError as exc:
            with lock:
                self._received += 1
                dropped[exc.reason] = dropped.get(exc.reason, 0) + 1
            return
        if type(sample) is ClockEcho:
            with lock:
                self._echoes += 1
                self._headset_clock.add(sample, received_mono)
            return
        if type(sample) is Confirm:
            self._confirm(sample, received_mono, now)
            return
        with lock:
            self._received += 1
            seq_status = self._tracker.update(sample.seq)
            if seq_status is SeqStatus.STALE:
                dropped['stale'] += 1
                return
            if seq_status is SeqStatus.RESTART:
                self._headset_clock.restart()   # a new app: a new clock origin
            stamp = self._stamp(sample.stamp, received_mono, now)
            if self.require_valid and not sample.eye_tracking_valid:
                dropped['eye_tracking_invalid'] += 1
                return
        try:
            q = ray_orientation(sample.gaze_direction)
        except GeometryError:  # parse_datagram already rejects these; kept as a guard
            with lock:
                dropped['zero_vector'] += 1
            return

        gaze = PoseStamped()
        gaze.header.stamp = stamp
        gaze.header.frame_id = self.frame_id
        p, o = gaze.pose.position, gaze.pose.orientation
        p.x, p.y, p.z = sample.gaze_origin.tolist()
        o.x, o.y, o.z, o.w = q.tolist()
        self._gaze_pub.publish(gaze)   # first: the gaze is what the control loop waits for
        # A head pose nobody listens to (nothing in the graph does, bar a recorder) is not built.
        if self._head_pub.get_subscription_count():
            head = PoseStamped()
            head.header.stamp = stamp
            head.header.frame_id = self.frame_id
            p, o = head.pose.position, head.pose.orientation
            p.x, p.y, p.z = sample.head_position.tolist()
            o.x, o.y, o.z, o.w = sample.head_orientation.tolist()
            self._head_pub.publish(head)
        with lock:
            self._published += 1

    def _confirm(self, press: Confirm, received_mono: float, now) -> None:
        key = (press.press_id, press.stamp)
        with self._lock:
            if key in self._confirm_seen:
                self._confirm_repeats += 1
                return
            self._confirm_seen.append(key)
            stamp = self._stamp(press.stamp, received_mono, now, record=False)
            self._confirms += 1
        self._confirm_pub.publish(Header(stamp=stamp, frame_id=CONFIRM_SOURCE))

    def _stamp(self, capture_headset: float, received_mono: float, now, record: bool = True):
        """The header stamp of a sample: its capture time in ROS time when the clock estimate
        allows, else `now` (its receipt). Called with the lock held. record: count it in the
        gaze's delay figures."""
        estimate = self._headset_clock.estimate()
        if estimate is None or self.stamp_source != 'capture':
            return now.to_msg()
        delay, why = capture_delay(estimate, capture_headset, received_mono, MAX_DELAY_S)
        if delay is None:
            if why == 'future':   # the headset's clock jumped ahead (a restarted app)
                self._headset_clock.restart()
            self._stamp_fallbacks += 1
            return now.to_msg()
        if record:
            if len(self._delays) < DELAY_BUFFER:
                self._delays.append(delay)
            self._captured += 1
        return (now - Duration(nanoseconds=int(delay * 1e9))).to_msg()

    def _ping(self) -> None:
        with self._lock:
            seq = self._ping_seq
            self._ping_seq = (seq + 1) % 2 ** 32
        try:
            self._sock.sendto(encode_ping(seq, time.monotonic()), self._ping_target)
        except OSError as exc:
            self.get_logger().warn(f'clock ping to {self._ping_target[0]}:{self._ping_target[1]} failed: {exc}',
                                   throttle_duration_sec=10.0)

    def clock_estimate(self):
        """The current ClockEstimate (None before enough exchanges), for tests and tools."""
        with self._lock:
            return self._headset_clock.estimate()

    # --- diagnostics ----------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        with self._lock:
            received, published = self._received, self._published
            seq_received, seq_lost = self._tracker.received, self._tracker.lost
            loss_rate, restarts = self._tracker.loss_rate, self._tracker.restarts
            dropped = dict(self._dropped)
            delays, self._delays = self._delays, []
            clock = self._headset_clock
            estimate, clock_restarts, echoes = clock.estimate(), clock.restarts, self._echoes
            clock_rejected = sum(clock.rejected.values())
            captured, fallbacks = self._captured, self._stamp_fallbacks
            confirms, confirm_repeats = self._confirms, self._confirm_repeats
        last_received, last_published, last_seq_received, last_seq_lost, last_time = self._last
        self._last = (received, published, seq_received, seq_lost, now)
        dt = max(now - last_time, 1e-9)
        new_received, new_published = received - last_received, published - last_published
        new_seq = (seq_received - last_seq_received) + (seq_lost - last_seq_lost)
        period_loss = (seq_lost - last_seq_lost) / new_seq if new_seq else 0.0
        new_dropped = new_received - new_published

        if new_received == 0:
            level, message = DiagnosticStatus.WARN, f'no datagram for {dt:.1f} s'
        elif new_published == 0:
            level, message = DiagnosticStatus.WARN, (f'no gaze published for {dt:.1f} s: all {new_received} '
                                                     'datagrams dropped')
        elif period_loss > MAX_LOSS_RATE:
            level, message = DiagnosticStatus.WARN, f'{100 * period_loss:.1f} % of samples lost over {dt:.1f} s'
        else:
            level, message = DiagnosticStatus.OK, f'{new_published / dt:.1f} Hz gaze'
            if new_dropped:
                message += f', {new_dropped} datagrams dropped'
        values = {
            'bind_address': f'{self.bind_address}:{self.port}',
            'received': received,
            'published': published,
            'dropped': sum(dropped.values()),
            **{f'dropped_{reason}': count for reason, count in dropped.items()},
            'lost': seq_lost,
            'loss_rate': f'{loss_rate:.4f}',
            'loss_rate_period': f'{period_loss:.4f}',
            'sender_restarts': restarts,
            'receive_rate_hz': f'{new_received / dt:.1f}',
            'publish_rate_hz': f'{new_published / dt:.1f}',
            'receive_buffer_bytes': self.receive_buffer_bytes,
            'confirms': confirms,
            'confirm_repeats': confirm_repeats,
            **self._clock_values(estimate, now, delays, echoes, clock_restarts, clock_rejected, captured,
                                 fallbacks),
        }
        publish_diagnostics(self, self._diag_pub, [status(
            self, 'gaze stream', level, message, values,
            hardware_id='HoloLens ' + (self.headset_address or ', '.join(sorted(map(str, self.allowed_senders)))))])

    def _clock_values(self, estimate, now, delays, echoes, restarts, rejected, captured, fallbacks) -> dict:
        if self._ping_target is None:
            state = 'no headset_address'
        elif estimate is None:
            state = 'waiting for clock echoes' if not restarts else 'restarted, waiting for echoes'
        elif estimate.carried_at(now) > MAX_CARRIED_S:
            state = 'no recent clock echo: stamped on receipt'   # the headset stopped answering pings
        else:
            state = 'synchronised'
        values = {
            'stamp_source': 'capture' if state == 'synchronised' and self.stamp_source == 'capture' else 'receipt',
            'clock_state': state,
            'clock_echoes': echoes,
            'clock_restarts': restarts,
            'clock_rejected': rejected,
            'stamped_capture': captured,
            'stamp_fallbacks': fallbacks,
        }
        if estimate is not None:
            values.update({
                'clock_offset_s': f'{estimate.offset_at(now):.6f}',
                'clock_drift_ppm': f'{estimate.drift * 1e6:.1f}',
                'clock_rtt_min_ms': f'{estimate.rtt_min * 1e3:.3f}',
                'clock_bound_ms': f'{estimate.bound_at(now) * 1e3:.3f}',
                'clock_exchanges': estimate.exchanges,
            })
        if delays:
            d = sorted(delays)
            values.update({
                'delay_p50_ms': f'{d[len(d) // 2] * 1e3:.3f}',
                'delay_p99_ms': f'{d[min(len(d) - 1, int(0.99 * len(d)))] * 1e3:.3f}',
                'delay_max_ms': f'{d[-1] * 1e3:.3f}',
            })
        return values

    # --- shutdown -------------------------------------------------------------------------

    def safe_shutdown(self) -> None:
        """Stop the receiver thread and close the socket (idempotent)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(5 * RECEIVE_TIMEOUT_S + 1.0)
        self._sock.close()

    def destroy_node(self):
        if hasattr(self, '_thread'):
            self.safe_shutdown()
        return super().destroy_node()


def main(args=None):
    return run(lambda: GazeBridge(), args)


if __name__ == '__main__':
    sys.exit(main())
