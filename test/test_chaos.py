"""The chaos run: its checker on synthetic register logs (each invariant can fail), the mock
PLC's register log, the supervisor's restarts, and a short seeded run on the lab graph held to
every invariant (`make chaos SEED=...` runs the long form)."""
import json
import signal

import pytest

from fabric_guidance.bench import chaos
from fabric_guidance.plc import RegisterMap
from fabric_guidance.plc.mock_server import _Registers
from fabric_guidance.plc.register_log import (Entry, Fault, RegisterLog, gate_breaches, late_vents, over_p_max,
                                              parse_line, vent_time)
from rosgraph import CONFIG, Graph, wait_until

P_MAX_COUNTS = 3750
ON, OFF = (2450, 2450, 0), (0, 0, 0)


def entries(*pairs):
    """Entries from (t, counts) pairs, sent as applied."""
    return [Entry(t, 'write', c, max(c)) for t, c in pairs]


# ------------------------------------------------------------------------ the checker alone
def test_a_write_above_p_max_is_caught_even_though_the_plc_clamped_it():
    log = entries((1.0, ON), (2.0, OFF)) + [Entry(3.0, 'write', (P_MAX_COUNTS, 0, 0), P_MAX_COUNTS + 1)]
    found = over_p_max(log, P_MAX_COUNTS)
    assert len(found) == 1 and '3751 counts' in found[0] and 't=3.000' in found[0]
    assert over_p_max(log[:2], P_MAX_COUNTS) == []


def test_a_late_vent_is_caught_and_one_in_time_is_not():
    log = entries((0.0, ON), (11.5, OFF))
    late = Fault('SIGKILL of plc_output', 10.0, 1.0, t_end=13.0)
    assert vent_time(log, 10.0, late.held_until) == pytest.approx(1.5)
    found = late_vents(log, [late], drained=14.0)
    assert len(found) == 1 and 'vented after 1.500 s (deadline 1.000 s)' in found[0]
    assert late_vents(entries((0.0, ON), (10.5, OFF)), [late], drained=14.0) == []


def test_a_vent_that_does_not_hold_until_the_fault_ends_is_not_a_vent():
    """A calibration's vented rest between two steps is not the vent the fault owes."""
    log = entries((0.0, ON), (10.2, OFF), (10.5, ON), (12.5, OFF))
    fault = Fault('SIGSTOP of pressure_controller', 10.0, 1.0, t_end=12.0)
    assert vent_time(log, 10.0) == pytest.approx(0.2)          # the first zero after the fault
    assert vent_time(log, 10.0, fault.held_until) is None     # not vented when it ended
    found = late_vents(log, [fault], drained=13.0)
    assert len(found) == 1 and 'pressure again 0.500 s after it, before the fault ended at 2.000 s' in found[0]


def test_a_vent_in_time_then_guidance_after_a_quick_respawn_passes():
    """Seed 19's shape: gaze_bridge killed at 321.609 s, the respawned process started 0.6 s
    later, the vent at 0.295 s, guidance back at 0.944 s, all inside the 0.953 s deadline. The
    vent held while the fault lasted; the resume came after it ended."""
    t = 321.609
    log = entries((300.0, ON), (t + 0.295, OFF), (t + 0.944, ON))
    healed = Fault('SIGKILL of gaze_bridge + headset_display', t, 0.953, t_end=t + 0.6)
    assert late_vents(log, [healed], drained=t + 2.0) == []
    # The same log fails when the fault was still on at the resume, or when no vent came in time.
    lasting = Fault(healed.kind, t, 0.953, t_end=t + 1.5)
    assert 'pressure again 0.944 s after it' in late_vents(log, [lasting], drained=t + 2.0)[0]
    never = entries((300.0, ON), (t + 1.2, OFF), (t + 1.3, ON))
    assert 'vented after 1.200 s (deadline 0.953 s)' in late_vents(never, [healed], drained=t + 2.0)[0]
    assert late_vents(entries((300.0, ON)), [healed], drained=t + 2.0) != []


def test_a_fault_is_judged_only_once_the_log_covers_its_end():
    log = entries((0.0, ON))
    fault = Fault('gaze stream paused', 10.0, 0.95, t_end=12.0)
    assert late_vents(log, [fault], drained=11.0) == []
    assert len(late_vents(log, [fault], drained=12.5)) == 1


def test_pressure_after_a_restart_before_the_operators_enable_breaks_the_gate():
    kill = Fault('SIGKILL of pressure_controller', 10.0, 1.02, t_end=10.6, t_enable=14.0)
    breach = entries((0.0, ON), (10.5, OFF), (12.0, ON), (15.0, OFF))
    found = gate_breaches(breach, [kill])
    assert len(found) == 1 and 't=12.000' in found[0] and '2.000 s before the operator enabled' in found[0]
    after_enable = entries((0.0, ON), (10.5, OFF), (14.2, ON))
    assert gate_breaches(after_enable, [kill]) == []
    # A fault without a restarted controller has no gate to hold.
    assert gate_breaches(breach, [Fault('SIGKILL of plc_output', 10.0, 1.01, t_end=10.6)]) == []


def test_a_broken_log_line_names_the_file_and_line(tmp_path):
    path = tmp_path / 'register_log.jsonl'
    path.write_text('{"t_ns": 1000000000, "cause": "write", "counts": [0, 0], "sent_max": 0}\n{"t_ns": "x"}\n')
    with pytest.raises(ValueError, match=r'register_log.jsonl:2: not a register log line'):
        RegisterLog(path).poll()
    assert parse_line('', 'f') is None
    assert parse_line('{"drained_ns": 2000000000}', 'f') == 2.0


def test_the_log_is_read_as_it_grows_a_partial_line_waiting(tmp_path):
    path = tmp_path / 'register_log.jsonl'
    line = json.dumps({'t_ns': 1_000_000_000, 'cause': 'write', 'counts': [5, 0], 'sent_max': 5})
    path.write_text(line + '\n' + line[:10])
    log = RegisterLog(path).poll()
    assert [e.counts for e in log.entries] == [(5, 0)]
    with open(path, 'a') as f:
        f.write(line[10:] + '\n' + json.dumps({'drained_ns': 3_000_000_000}) + '\n')
    log.poll()
    assert len(log.entries) == 2 and log.drained == 3.0


def test_the_mock_plc_logs_applied_changes_the_watchdog_and_an_over_limit_write():
    regmap = RegisterMap.load(CONFIG / 'hardware' / 'plc_register_map.yaml')
    import threading
    regs = _Registers(regmap, threading.RLock())
    regs.register_log = []
    first = regmap.command_registers[0]
    seq = regmap.sequence_register
    block = list(range(first, seq + 1))
    values = [0] * len(block)
    values[0], values[-1] = 100, 1
    regs.write(first, values)                       # applied: logged
    regs.write(first, values[:-1] + [2])            # same commands, newer number: not logged
    over = list(values)
    over[1], over[-1] = regmap.p_max_counts + 7, 3
    regs.write(first, over)                         # clamped, but logged with what was sent
    regs.force_commands_zero()                      # the watchdog's vent
    causes = [(cause, counts[:2], sent) for _, cause, counts, sent in regs.register_log]
    assert causes == [('write', (100, 0), 100), ('write', (100, regmap.p_max_counts), regmap.p_max_counts + 7),
                      ('watchdog', (0, 0), 0)]
    log = [Entry(t * 1e-9, c, s, m) for t, c, s, m in regs.register_log]
    assert len(over_p_max(log, regmap.p_max_counts)) == 1


def test_the_schedule_is_the_seeds_and_covers_every_kind_each_round():
    a, b = chaos.schedule(7, 40), chaos.schedule(7, 40)
    assert a == b and chaos.schedule(8, 40) != a and len(a) == 40
    first_round = a[:19]
    for node in chaos.NODES:
        assert chaos.Planned('kill', (node,)).kind in {p.kind for p in first_round}
        assert any(p.action == 'stop' and p.nodes == (node,) for p in first_round)
    assert sum(len(p.nodes) == 2 and p.action in ('kill', 'stop') for p in first_round) == 2
    assert {p.action for p in first_round} >= {'link_drop', 'link_delay', 'gaze_pause', 'gaze_flood',
                                               'freeze_kill'}
    assert all(p.deadline_s is None or p.hold_s > p.deadline_s for p in a)


def test_every_round_ends_with_the_operators_calls_and_a_seeds_first_faults_stay():
    a = chaos.schedule(7, 44)
    rounds = [a[:22], a[22:44]]     # 19 process, link and gaze faults, 2 operator's calls, 1 second writer
    for r in rounds:
        assert [p.action for p in r[-3:]] == ['disable', 'vent_cycle', 'two_writers']
        assert r[-3].phase == 'calibration' and r[-3].deadline_s == chaos.OPERATOR_VENT_S
    # The faults before them are drawn as before the operator's calls existed (seed 19's five).
    assert [p.kind for p in chaos.schedule(19, 5)] == [p.kind for p in chaos.schedule(19, 40)[:5]]


# ------------------------------------------------------------------- the supervisor alone
@pytest.mark.graph
def test_the_supervisor_restarts_a_killed_node_and_stop_all_leaves_nothing(tmp_path):
    graph = Graph(tmp_path / 'logs')
    try:
        first = graph.start('target_selector', ('params/guidance.yaml',))
        graph.supervise('target_selector', delay_s=0.2)
        wait_until(lambda: 'live targets' in graph.log('target_selector'), 30.0, what='target_selector up')
        first.send_signal(signal.SIGKILL)
        wait_until(lambda: graph.restart_count('target_selector') == 1, 10.0, what='the restart')
        (restart,) = graph.restarts
        assert restart.returncode == -signal.SIGKILL and restart.pid != first.pid
        assert restart.started - restart.died >= 0.2
        # The new process logs after its predecessor, in the same file.
        wait_until(lambda: graph.log('target_selector').count('live targets') == 2, 30.0, what='the new one up')
        # Stopped on purpose: not restarted.
        assert graph.stop('target_selector') == 0
        assert graph.restart_count('target_selector') == 1
    finally:
        graph.stop_all()
    assert graph.leftovers() == []
    assert len(graph.pids) == 2


# ------------------------------------------------------------------ a short run on the graph
@pytest.mark.graph
def test_a_short_seeded_chaos_run_holds_every_invariant(tmp_path, capsys):
    # Seed 19's five faults: plc_output and the controller stopped together (calibrating),
    # plc_output stopped, the controller killed (its restart must wait for enable), bridge and
    # display killed together, the Modbus link dropped.
    rows, violations = chaos.run_chaos(19, 5, tmp_path, print)
    assert violations == []
    summary = json.loads((tmp_path / 'chaos.json').read_text())
    kinds = {r['kind'] for r in rows}
    assert 'SIGKILL of pressure_controller' in kinds and 'Modbus link drops every byte' in kinds
    for r in rows:
        if r['deadline_s'] is not None:
            assert r['worst_vent_s'] is not None and r['worst_vent_s'] <= r['deadline_s'], r
    killed = [f for f in summary['faults_run'] if f['kind'] == 'SIGKILL of pressure_controller']
    assert killed and all(f['enabled_after_s'] is not None for f in killed)
    assert summary['restarts'] >= 3   # the controller, the bridge, the display
    assert '| fault | count |' in (tmp_path / 'chaos.md').read_text()


@pytest.mark.graph
def test_the_operators_enable_false_and_vent_cycle_hold_until_enable(tmp_path):
    """enable false during a calibration, and vent then deactivate/activate: every register at 0
    within OPERATOR_VENT_S of the call, nothing applied before the operator's enable (read from
    the mock PLC's register log), guidance back after it."""
    plan = [chaos.Planned('disable', (), 'calibration', 1.6), chaos.Planned('vent_cycle', (), 'guidance', 1.6),
            chaos.Planned('vent_cycle', (), 'calibration', 1.6)]
    rows, violations = chaos.run_chaos(0, len(plan), tmp_path, print, plan=plan)
    assert violations == []
    summary = json.loads((tmp_path / 'chaos.json').read_text())
    assert len(summary['faults_run']) == 3
    for f in summary['faults_run']:
        assert f['vent_s'] is not None and f['vent_s'] <= chaos.OPERATOR_VENT_S, f
        assert f['enabled_after_s'] is not None and f['enabled_after_s'] >= 1.6, f
        print(f"{f['kind']} ({f['phase']}): registers at 0 {f['vent_s']:.3f} s after the call "
              f"(deadline {chaos.OPERATOR_VENT_S:.3f} s)")


def test_a_foreign_writers_command_is_judged_held_out_only_while_plc_outputs_claim_held():
    """plc_output's own request can time out under load during the writer's refusals;
    its dropped connection frees the PLC's claim and the writer's command is applied before the
    kill. With inject's claim_freed that is no breach; without it, it is one."""
    from fabric_guidance.bench.second_writer import breaches
    pattern = (2000, 2000, 2000)
    log = entries((1.0, ON), (3.0, pattern), (4.0, OFF), (9.0, ON))
    w = {'t_start': 2.0, 't_kill': 5.0, 't_die': 6.0, 't_closed': 6.5, 'refused': 40, 'codes': [6],
         'pattern': pattern}
    found = breaches(log, [('a foreign Modbus writer', w)], 1.01, 10.0)
    assert len(found) == 1 and 'applied at t=3.000 s while plc_output held the PLC' in found[0]
    assert breaches(log, [('a foreign Modbus writer', {**w, 'claim_freed': 3.0})], 1.01, 10.0) == []
