"""What a loaded machine adds to a Modbus round trip on top of a delay injected on the link.

PlcClient writes a command vector at 50 Hz through FaultProxy (``--delay-ms`` each way) to a
MockPlcServer in another process, as plc_output writes to mock_plc in the link-fault tests; the
figures are each round trip minus twice the injected delay. A test that injects a delay "below
the timeout" must leave at least the worst of these figures between 2 x delay and the client's
timeout, or a loaded machine turns its slow link into a failed one. Run it beside the load the
tests see (the other test worker, `make flakes`' stress):

    python -m fabric_guidance.bench.link_margin --delay-ms 60 --seconds 30
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from ..paths import config_path
from ..plc import PlcClient, RegisterMap
from .faultproxy import FaultProxy

_SERVER = '''
import sys, time
from fabric_guidance.paths import config_path
from fabric_guidance.plc import RegisterMap
from fabric_guidance.plc.mock_server import MockPlcServer
with MockPlcServer(RegisterMap.load(config_path("hardware/plc_register_map.yaml")), watchdog_s=60.0,
                   regulator_tau_s=0.0) as plc:
    print(plc.port, flush=True)
    sys.stdin.read()
'''


def measure(delay_s: float, seconds: float, timeout_s: float = 0.2, rate_hz: float = 50.0) -> dict:
    """Round trips through the delaying proxy for `seconds`; the excess over 2 x delay [ms]."""
    regmap = RegisterMap.load(config_path('hardware/plc_register_map.yaml'))
    server = subprocess.Popen([sys.executable, '-c', _SERVER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        port = int(server.stdout.readline())
        round_trips, failures = [], 0
        with FaultProxy('127.0.0.1', port) as proxy:
            client = PlcClient(regmap, '127.0.0.1', proxy.port, timeout_s=timeout_s)
            client.connect()
            proxy.delay(delay_s)
            end, k = time.monotonic() + seconds, 0
            while time.monotonic() < end:
                k += 1
                t0 = time.monotonic()
                try:
                    client.write_pressures([10.0 + k % 50] * len(regmap.channels))
                    round_trips.append(time.monotonic() - t0)
                except Exception:   # a timed-out request: what the margin is there to prevent
                    failures += 1
                    client.close()
                    client.connect()
                time.sleep(max(0.0, 1.0 / rate_hz - (time.monotonic() - t0)))
            client.close()
    finally:
        server.stdin.close()
        server.wait(timeout=10)
    excess = (np.asarray(round_trips) - 2 * delay_s) * 1e3
    figures = {'delay_ms_each_way': delay_s * 1e3, 'timeout_ms': timeout_s * 1e3, 'round_trips': len(round_trips),
               'failures': failures, 'load_1min': round(os.getloadavg()[0], 2)}
    for name, q in (('p50', 50), ('p99', 99), ('p999', 99.9)):
        figures[f'excess_{name}_ms'] = round(float(np.percentile(excess, q)), 1) if len(excess) else None
    figures['excess_max_ms'] = round(float(excess.max()), 1) if len(excess) else None
    return figures


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='python -m fabric_guidance.bench.link_margin', description=__doc__.split('\n')[0])
    ap.add_argument('--delay-ms', type=float, default=60.0, help='delay injected each way [ms] (default 60)')
    ap.add_argument('--seconds', type=float, default=30.0, help='how long to write [s] (default 30)')
    ap.add_argument('--timeout-ms', type=float, default=200.0, help="the client's request timeout [ms] (default 200)")
    args = ap.parse_args(argv)
    print(json.dumps(measure(args.delay_ms / 1e3, args.seconds, args.timeout_ms / 1e3)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
