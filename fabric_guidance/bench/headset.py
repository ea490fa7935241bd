"""Capture to register with the compiled C# headset as the gaze source (hololens/,
HeadsetHarness.exe under mono): the bench's sweep as a pose file, sent by the headset's own
encoder and socket, each frame's capture time taken from its log on the headset's clock and
mapped to CLOCK_MONOTONIC with gaze_bridge's own clock estimate (its /diagnostics offset), then
matched to the mock PLC's write log as the Python sender's samples are.

What it adds to the gaze-to-register figure: mono's send path, and the error of the clock
estimate, which the figure carries (the bound is printed beside it).
"""
from __future__ import annotations

import json
from pathlib import Path
import shutil
import socket
import subprocess
import time

import numpy as np

from ..graph.process_graph import free_port, wait_until
from .build_lock import locked_run
from .latency import landings, percentiles_ms
from .stages import account

HOLOLENS = Path(__file__).resolve().parents[2] / 'hololens'
#: The harness's seq starts far from the priming sender's (a seq just behind would be stale).
SEQ_START = 1_000_000
SETTLE_S = 1.0


def unavailable() -> str | None:
    """Why the C# headset cannot run here, or None."""
    missing = [tool for tool in ('mcs', 'mono', 'make') if shutil.which(tool) is None]
    if missing:
        return f'{", ".join(missing)} not installed (make system-deps)'
    if not (HOLOLENS / 'Makefile').is_file():
        return f'{HOLOLENS} is not here (run from a source checkout)'
    # One make of hololens/ at a time: a test beside the bench may build it too.
    built = locked_run(['make', '--no-print-directory', '-C', str(HOLOLENS), 'all'], HOLOLENS / 'build~', 300)
    return None if built.returncode == 0 else f'hololens/ did not build: {built.stderr.strip()[-300:]}'


def capture_to_register(work: Path, say, rate_hz: float, n: int, warmup_s: float) -> dict:
    """n frames at rate_hz from the C# headset after warmup_s of the same stream; the latency
    from each frame's capture to its value in the register [ms]."""
    from .graphs import PackageGraph
    reason = unavailable()
    if reason is not None:
        return {'skipped': reason}
    from diagnostic_msgs.msg import DiagnosticArray
    from ..interface import DIAGNOSTICS

    listen = free_port(socket.SOCK_DGRAM)
    work.mkdir(parents=True, exist_ok=True)
    pkg = PackageGraph(work, say, overrides={'gaze_bridge': dict(headset_address='127.0.0.1', display_port=listen)})
    try:
        clock: list[dict] = []

        def on_diagnostics(msg):
            for st in msg.status:
                if st.name == 'gaze_bridge: gaze stream':
                    v = {kv.key: kv.value for kv in st.values}
                    if v.get('clock_state') == 'synchronised':
                        clock.append(v)
        pkg.probe.subscribe(DiagnosticArray, DIAGNOSTICS, 10, on_diagnostics)
        pkg.rig.prime()
        mark = pkg.stages.snapshot()
        sweep = pkg.sweep
        poses = work / 'sweep_poses.jsonl'
        with poses.open('w') as f:
            for i in range(sweep.levels):
                d = json.loads(sweep.datagram(i, rate_hz))
                f.write(json.dumps({k: d[k] for k in ('gaze_origin', 'gaze_direction', 'head_position',
                                                      'head_orientation')} | {'valid': True}) + '\n')
        warm = int(round(warmup_s * rate_hz))
        frames = warm + n
        log = work / 'harness.log'
        # Synchronised before the measured frames: the bridge pings every 0.2 s.
        t0 = time.monotonic()
        proc = subprocess.run(
            ['mono', str(HOLOLENS / 'build~' / 'HeadsetHarness.exe'), '--uplink', f'127.0.0.1:{pkg.gaze_port}',
             '--listen', f'127.0.0.1:{listen}', '--poses', str(poses), '--rate', str(rate_hz),
             '--frames', str(frames), '--duration', str(frames / rate_hz + 2.0), '--seq-start', str(SEQ_START),
             '--clock-offset', '0', '--log', str(log)], capture_output=True, text=True, timeout=frames / rate_hz + 60)
        t1 = time.monotonic()
        if proc.returncode != 0:
            return {'skipped': f'the harness failed: {proc.stderr.strip()[-300:]}'}
        pkg.log.wait_drained(time.monotonic_ns() + int(SETTLE_S * 1e9))
        wait_until(lambda: clock, 5.0, what="gaze_bridge's clock estimate")
        offset = float(np.median([float(v['clock_offset_s']) for v in clock]))
        bound_ms = max(float(v['clock_bound_ms']) for v in clock)
        stamps = [e['stamp'] for e in map(json.loads, log.read_text().splitlines()) if 'sent' in e]
        sent_ns = [int(round((s - offset) * 1e9)) for s in stamps]
        landed = landings(sent_ns, pkg.log.writes(sent_ns[0]), sweep.register, sweep.level_of, sweep.levels)
        latencies = [landed[i] - sent_ns[i] for i in range(warm, len(sent_ns)) if i in landed]
        after = pkg.stages.snapshot()
        acc = account(mark, after, len(sent_ns), len(landed), pkg.stages.warnings([(t0, t1)]))
        return {**percentiles_ms(latencies), 'applied': len(latencies), 'sent': len(sent_ns) - warm,
                'clock_bound_ms': bound_ms, 'clock_offset_s': offset, 'stages': acc,
                # The rate the headset's frames left at (their capture stamps), against rate_hz.
                'rate_hz_sent': float(1.0 / np.median(np.diff(stamps))) if len(stamps) > 1 else None}
    finally:
        pkg.close()
