"""The chaos run's second Modbus writer: a second plc_output or a tool on the same PLC.

It writes straight to mock_plc while plc_output holds the PLC's write claim (every write must
be refused with exception 06 and never applied); plc_output is then killed, the second writer
takes the PLC and holds SECOND_WRITER_KPA with its own heartbeat, and falls silent with its
connection open (a half-open link: the death the PLC sees last). From then every command
register must read 0 within the watchdog's deadline, its command must never come back, and
the respawned plc_output must guide again (after the operator's enable when it was kept out
long enough to request the PLC's vent: docs/safety.md, "A stop from any connection"). Judged
from the register log alone.
"""
from __future__ import annotations

import os
import signal
import threading
import time

from ..plc.register_log import vent_time
from ..graph.process_graph import CONFIG, wait_until

#: What the second writer commands on every channel [kPa]: no guidance or calibration pattern,
#: so it is recognisable in the register log.
SECOND_WRITER_KPA = 200.0
#: Its write period [s] (plc_output's) and request timeout [s].
WRITE_PERIOD_S, MODBUS_TIMEOUT_S = 1 / 50, 0.2
#: Deadlines [s]: its command applied once plc_output died; plc_output back; the log drained.
TAKEOVER_S, RECOVERY_S, DRAIN_S = 5.0, 45.0, 10.0


class SecondWriter:
    """A second Modbus client straight on mock_plc (a second plc_output, a tool): commands
    SECOND_WRITER_KPA on every channel with its own heartbeat at 50 Hz, counting the refusals
    (exception 06) it gets while another client holds the PLC's write claim. `silence()`: it
    stops writing and keeps its connection open (a half-open link, the hardest death to see)."""

    def __init__(self, client):
        self.client, self.refused, self.refused_codes, self.failed = client, 0, set(), 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='second-writer', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from ..plc.modbus import PlcLinkError, PlcRefusedError
        beat, n = 0, len(self.client.map)
        while not self._stop.is_set():
            beat += 1
            try:
                self.client.write_heartbeat(beat)
                self.client.write_pressures([SECOND_WRITER_KPA] * n)
            except PlcRefusedError as exc:
                self.refused += 1
                self.refused_codes.add(exc.code)
            except PlcLinkError:
                self.failed += 1
            self._stop.wait(WRITE_PERIOD_S)

    def silence(self) -> None:
        self._stop.set()
        self._thread.join(2)

    def close(self) -> None:
        self.silence()
        self.client.close()


def inject(lab, index: int, hold_s: float, kind: str, vent_deadline_s: float) -> dict:
    """The fault on a ChaosLab (its graph, register log, PLC port); returns its timeline: t_start,
    t_kill, t_die (the fault's time), refusals before the kill and their codes, the command
    pattern in counts, recovery_s (guidance back after t_die), t_closed (its connection closed),
    and claim_freed when plc_output's own link failed before the kill and the writer's command
    was applied from then (the claim it held was freed with its connection)."""
    from ..plc import PlcClient, RegisterMap
    g, log = lab.graph, lab.register_log
    regmap = RegisterMap.load(CONFIG / 'hardware' / 'plc_register_map.yaml')
    pattern = tuple(regmap.encode([SECOND_WRITER_KPA] * len(regmap)))
    writer = SecondWriter(PlcClient(regmap, '127.0.0.1', lab.plc_port, timeout_s=MODBUS_TIMEOUT_S))
    t_start = time.monotonic()
    before = len(g.log('plc_output'))
    try:
        time.sleep(hold_s / 2)   # refused all along (a fixed span, not a wait for anything)
        w = {'t_start': t_start, 'refused': writer.refused, 'codes': sorted(writer.refused_codes),
             'pattern': pattern}
        restarts = g.restart_count('plc_output')
        lab.mark_log('plc_output')
        logged = len(g.log('plc_output'))
        w['t_kill'] = time.monotonic()
        # plc_output's own link may have failed meanwhile (a request timing out on a loaded
        # machine: its client drops the connection, and a closed connection frees the PLC's
        # claim), and the writer taken the freed claim before the kill.
        early = [e.t for e in log.poll().entries if t_start <= e.t <= w['t_kill'] and e.counts == pattern]
        if early and 'link lost' in g.log('plc_output')[before:logged]:
            w['claim_freed'] = early[0]
        os.kill(g.processes['plc_output'].pid, signal.SIGKILL)
        if 'claim_freed' not in w:
            wait_until(lambda: any(e.counts == pattern for e in log.poll().entries if e.t > w['t_kill']),
                       TAKEOVER_S, what=f'fault {index}: the second writer holding the PLC after plc_output died')
        time.sleep(max(0.0, w['t_kill'] + hold_s / 2 - time.monotonic()))
        w['t_die'] = time.monotonic()
        writer.silence()
        wait_until(lambda: g.restart_count('plc_output') > restarts, RECOVERY_S, what='plc_output restarted')
        # Its command is still the last in the log (guidance is back once something else is),
        # unless the respawned plc_output's vent request has vented the PLC already.
        wait_until(lambda: vent_time(log.poll().entries, w['t_die']) is not None, RECOVERY_S,
                   what=f'fault {index}: the vent after the second writer fell silent')

        def back():
            # A plc_output kept out by this writer for two PLC watchdog times wrote the PLC's vent
            # request and vented the controller: the stop holds until the operator's enable. (The
            # one killed may have, after its own link failed: from the fault's start.)
            if 'operator_enable' not in w and 'controller vented:' in g.log('plc_output')[before:]:
                w['operator_enable'] = lab.enable()
            return not log.poll().entries[-1].vented and log.entries[-1].counts != pattern
        wait_until(back, RECOVERY_S, what=f'fault {index}: {kind}: guidance back')
        w['recovery_s'] = time.monotonic() - w['t_die']
    finally:
        writer.close()
        w['t_closed'] = time.monotonic()
    wait_until(lambda: log.poll().drained >= w['t_die'] + vent_deadline_s, DRAIN_S,
               what='the register log drained')
    return w


def breaches(entries, faults: list[tuple[str, dict]], vent_deadline_s: float, drained: float) -> list[str]:
    """Per (kind, timeline) of inject(): every broken invariant, one line each."""
    found = []
    for kind, w in faults:
        t = w['t_die']
        if drained < t + vent_deadline_s:
            continue
        where = f'{kind} at t={t:.3f} s'
        if not w['refused'] or w['codes'] != [6]:
            found.append(f'{where}: refused {w["refused"]} times (codes {w["codes"]}) while plc_output held the '
                         f'PLC; every write must get exception 06')
        # Until plc_output's own link failure freed the claim, if it did (inject's claim_freed).
        held_until = w.get('claim_freed', w['t_kill'])
        applied = [e for e in entries if w['t_start'] <= e.t < held_until and e.counts == w['pattern']]
        if applied:
            found.append(f'{where}: its command applied at t={applied[0].t:.3f} s while plc_output held the PLC')
        seconds = vent_time(entries, t)
        if seconds is None or seconds > vent_deadline_s:
            late = 'never' if seconds is None else f'after {seconds:.3f} s'
            found.append(f'{where}: vented {late} after it fell silent (deadline {vent_deadline_s:.3f} s)')
            continue
        # Until it closed its connection (a later fault's second writer is another client).
        back = [e for e in entries if t + seconds < e.t <= w['t_closed'] and e.counts == w['pattern']]
        if back:
            found.append(f'{where}: its command applied again at t={back[0].t:.3f} s, after the vent')
    return found
