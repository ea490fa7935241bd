"""mock_plc: a simulated pressure PLC on Modbus TCP, for tests and the demo.

Runs fabric_guidance.plc.MockPlcServer (the PLC contract of docs/plc.md: same register map as
the real PLC, regulator lag, heartbeat watchdog, sequence gate, clamp) for one endpoint of the
register map (`endpoint`; one mock_plc per PLC) and reports what was written to it: the
largest pressure ever written per channel and, on /diagnostics, every write above p_max or
outside the register map.

Publishes: mock_plc/max_written_kpa (std_msgs/Float64MultiArray, kPa, channel order), /diagnostics

With write_log_file set (the benchmarks), every client write to the holding registers is also
appended to that file as `<CLOCK_MONOTONIC ns> <first address> <values...>`, and every drain
(20 Hz) ends with `# drained <ns>`: a reader knows every write before that time is in the file.

With register_log_file set (the chaos run), the command registers as applied are appended to that
file as JSON lines whenever they change (a client write, the watchdog's vent, a power-up) or a
write sends more than p_max: `{"t_ns", "cause", "counts", "sent_max"}`, each drain ending with
`{"drained_ns"}` (plc/register_log.py reads and checks it).
"""
from __future__ import annotations

import json
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from fabric_guidance.interface import DIAGNOSTICS
from fabric_guidance.nodes.array_layout import named_layout
from fabric_guidance.nodes.diagnostics import publish_diagnostics, status
from fabric_guidance.nodes.parameters import declare, declare_config_file
from fabric_guidance.nodes.qos import COMMAND_QOS
from fabric_guidance.nodes.spin import run
from fabric_guidance.interface import MAX_WRITTEN
from fabric_guidance.paths import resolve
from fabric_guidance.plc import MockPlcServer, PlcLayout


class MockPlc(Node):

    def __init__(self):
        super().__init__('mock_plc')
        host = declare(self, 'host', '127.0.0.1', 'address to listen on (Modbus TCP)', read_only=True)
        port = declare(self, 'port', 1502, 'TCP port to listen on (0: any free port)', '', 0, 65535,
                       read_only=True)
        register_map_file = declare_config_file(self, 'register_map_file', 'hardware/plc_register_map.yaml',
                                                'register map')
        endpoint = declare(self, 'endpoint', '',
                           "which PLC of a register map with endpoints to play; '' = the only one",
                           read_only=True)
        tau_s = declare(self, 'regulator_tau_s', 0.15, 'first-order lag of each electro-pneumatic regulator',
                        's', 0.0, 10.0, read_only=True)
        watchdog_s = declare(self, 'watchdog_s', 0.5, 'vent all channels when the heartbeat stops for this long',
                             's', 0.01, 3600.0, read_only=True)
        update_hz = declare(self, 'update_hz', 100.0, 'regulator simulation rate', 'Hz', 1.0, 1000.0,
                            read_only=True)
        records_file = declare(self, 'records_file', '',
                               "keep the write records here as JSON (plc/records.py); '' = none", read_only=True)
        status_rate_hz = declare(self, 'status_rate_hz', 10.0,
                                 'mock_plc/max_written_kpa and /diagnostics publication rate', 'Hz', 0.1, 100.0,
                                 read_only=True)

        # A lab PLC outlives the PC's processes; the mock one must not leave before plc_output's
        # vent on shutdown (one Ctrl-C reaches every process of `ros2 launch` at once).
        self.shutdown_grace_s = declare(self, 'shutdown_grace_s', 3.0,
                                        'on shutdown, wait up to this long for the clients '
                                        'to vent and disconnect', 's', 0.0, 60.0, read_only=True)
        write_log_file = declare(self, 'write_log_file', '',
                                 "append every holding-register write with its CLOCK_MONOTONIC time [ns] to this "
                                 "file (benchmarks); '' = off", read_only=True)

        register_log_file = declare(self, 'register_log_file', '',
                                    'append the command registers as applied, at every change, with their '
                                    "CLOCK_MONOTONIC time [ns], to this file (JSON lines); '' = off", read_only=True)

        layout = PlcLayout.load(resolve(register_map_file, 'hardware/plc_register_map.yaml'))
        self.register_map = layout.endpoint(endpoint).map
        self.server = MockPlcServer(self.register_map, host, port, regulator_tau_s=tau_s, watchdog_s=watchdog_s,
                                    update_hz=update_hz, records_path=records_file or None,
                                    time_writes=bool(write_log_file),
                                    log_registers=bool(register_log_file)).start()
        self._write_log = None
        if write_log_file:
            self._write_log = open(write_log_file, 'a')
            self.create_timer(0.05, self._drain_write_log, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._register_log = None
        if register_log_file:
            self._register_log = open(register_log_file, 'a')
            self.create_timer(0.05, self._drain_register_log, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.address = f'{host}:{self.server.port}'
        self._max_pub = self.create_publisher(Float64MultiArray, MAX_WRITTEN, COMMAND_QOS)
        self._max_layout = named_layout(self.register_map.names)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.create_timer(1.0 / status_rate_hz, self._on_status_timer, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'mock PLC listening on {self.address}: {len(self.register_map)} channels, '
                               f'p_max {self.register_map.p_max_kpa:g} kPa, regulator tau {tau_s:g} s, '
                               f'watchdog {watchdog_s:g} s')

    def _on_status_timer(self) -> None:
        written = self.server.max_written_kpa()
        self._max_pub.publish(Float64MultiArray(layout=self._max_layout,
                                                data=[float(written[name]) for name in self.register_map.names]))
        over, outside = len(self.server.over_limit_writes), len(self.server.out_of_map_writes)
        if over or outside:
            level = DiagnosticStatus.ERROR
            message = f'{over} writes above p_max, {outside} writes outside the register map'
        else:
            level, message = DiagnosticStatus.OK, 'every write within the register map and p_max'
        values = {'over-limit writes': over, 'out-of-map writes': outside,
                  'watchdog trips': self.server.watchdog_trips, 'watchdog armed': self.server.watchdog_armed,
                  'stale writes refused': len(self.server.stale_writes),
                  'max written kPa': f'{max(written.values()):g}', 'address': self.address}
        publish_diagnostics(self, self._diagnostics_pub, [status(
            self, 'mock PLC', level, message, values, hardware_id=f'mock PLC {self.address}')])

    def _drain_write_log(self) -> None:
        drained_ns = time.monotonic_ns()  # before the take: every write up to here is in it
        lines = [f'{t} {start} {" ".join(map(str, values))}\n' for t, start, values in self.server.take_write_times()]
        lines.append(f'# drained {drained_ns}\n')
        self._write_log.writelines(lines)
        self._write_log.flush()

    def _drain_register_log(self) -> None:
        drained_ns = time.monotonic_ns()
        lines = [json.dumps({'t_ns': t, 'cause': cause, 'counts': list(counts), 'sent_max': sent_max}) + '\n'
                 for t, cause, counts, sent_max in self.server.take_register_log()]
        lines.append(json.dumps({'drained_ns': drained_ns}) + '\n')
        self._register_log.writelines(lines)
        self._register_log.flush()

    def safe_shutdown(self) -> None:
        if not self.server.wait_until_vented(self.shutdown_grace_s):
            self.get_logger().warning(
                f'stopping with {self.server.client_count} client(s) connected and commands '
                f'{[float(v) for v in self.server.commands_kpa()]} kPa after '
                f'{self.shutdown_grace_s:g} s')
        self.server.stop()
        if self._write_log is not None:
            self._drain_write_log()
            self._write_log.close()
        if self._register_log is not None:
            self._drain_register_log()
            self._register_log.close()
        self.get_logger().info(f'mock PLC on {self.address} stopped')


def main(args=None):
    return run(lambda: MockPlc(), args)


if __name__ == '__main__':
    sys.exit(main())
