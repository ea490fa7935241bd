"""The soak run: the latency matcher and the drift verdict on synthetic data (each can fail),
and a short run on the simulated graph with its rows, verdict and plot (`make soak` runs the
long form)."""
import csv
import json
import math

import numpy as np
import pytest

from fabric_guidance.bench import soak, soak_report
from fabric_guidance.bench.soak import LatencyMatcher
from rosgraph import log_tails

MS = 1_000_000
VENTED = (0, 0)


def encode(kpa):
    return [int(round(10 * p)) for p in kpa]


def matcher_with(gazes, steps, commands, registers, drained_ns):
    """A matcher fed (key, capture) gazes, (published, step, key) steps, (published, kPa)
    commands and (applied, counts) register changes, then matched at drained_ns."""
    m = LatencyMatcher(encode, VENTED)
    for key, t in gazes:
        m.gaze(key, t)
    for published, step, key in steps:
        m.step(published, step, key)
    for published, kpa in commands:
        m.command(published, kpa)
    for applied, counts in registers:
        m.registers(applied, counts)
    m.update(drained_ns + 10 * soak.LAND_TIMEOUT_S * 1e9, drained_ns)
    return m


# ------------------------------------------------------------------ the matcher alone
def test_a_sample_is_timed_from_its_capture_to_the_registers_taking_its_command():
    m = matcher_with(gazes=[((1.0,), 0), ((2.0,), 16 * MS)],
                     steps=[(1 * MS, 0, (1.0,)), (17 * MS, 1, (2.0,))],
                     commands=[(1 * MS + 10, [1.0, 0.0]), (17 * MS + 10, [2.0, 0.0])],
                     registers=[(4 * MS, (10, 0)), (21 * MS, (20, 0))], drained_ns=2000 * MS)
    latencies, to_command, counts = m.take(10_000 * MS)
    assert latencies == [4 * MS, 5 * MS] and to_command == [1 * MS + 10, 1 * MS + 10]
    assert counts['changed'] == 2 and counts['not_landed'] == 0 and counts['steps_unseen'] == 0


def test_a_value_the_registers_held_before_the_command_was_published_is_not_its_landing():
    # The registers took (10, 0) at 3 ms from a command the run did not see; the command seen,
    # published at 33 ms with the same value, lands at 40 ms.
    m = matcher_with(gazes=[((3.0,), 32 * MS)], steps=[(33 * MS, 2, (3.0,))], commands=[(33 * MS + 10, [1.0, 0.0])],
                     registers=[(3 * MS, (10, 0)), (20 * MS, (0, 0)), (40 * MS, (10, 0))], drained_ns=2000 * MS)
    assert m.take(10_000 * MS)[0] == [8 * MS]


def test_a_command_that_never_reaches_the_registers_is_counted_lost_only_once_the_log_covers_it():
    args = dict(gazes=[((1.0,), 0)], steps=[(1 * MS, 0, (1.0,))], commands=[(1 * MS + 10, [1.0, 0.0])],
                registers=[])
    early = matcher_with(**args, drained_ns=500 * MS)
    assert early.counts['not_landed'] == 0 and not early.settled(2 * MS)
    late = matcher_with(**args, drained_ns=1100 * MS)
    assert late.counts['not_landed'] == 1 and late.settled(2 * MS)
    assert late.take(10_000 * MS)[0] == []


def test_steps_on_a_repeated_gaze_and_unchanged_commands_have_no_latency():
    m = matcher_with(gazes=[((1.0,), 0), ((1.0,), 16 * MS)],
                     steps=[(1 * MS, 0, (1.0,)), (17 * MS, 1, (1.0,)), (30 * MS, 3, (1.0,))],
                     commands=[(1 * MS + 10, [1.0, 0.0]), (17 * MS + 10, [1.5, 0.0]), (30 * MS + 10, [1.5, 0.0])],
                     registers=[(3 * MS, (10, 0)), (20 * MS, (15, 0))], drained_ns=2000 * MS)
    latencies, to_command, counts = m.take(10_000 * MS)
    assert latencies == [3 * MS]                     # the second change came on the same gaze
    assert to_command == [1 * MS + 10]
    assert counts['changed'] == 2 and counts['steps_unseen'] == 1


def test_a_command_waits_for_its_step_arriving_late_on_the_other_topic():
    m = LatencyMatcher(encode, VENTED)
    m.gaze((1.0,), 0)
    m.command(1 * MS + 10, [1.0, 0.0])
    m.registers(4 * MS, (10, 0))
    m.update(2 * MS, 10 * MS)
    assert m.counts['changed'] == 0                  # not paired yet: its step may still come
    m.step(1 * MS, 0, (1.0,))
    m.step(17 * MS, 1, (2.0,))
    m.update(18 * MS, 10 * MS)
    assert m.take(10_000 * MS)[0] == [4 * MS]


# ------------------------------------------------------------------ the verdict alone
def test_a_growing_figure_drifts_and_a_noisy_flat_one_does_not():
    rng = np.random.default_rng(3)
    t_h = np.arange(60) / 60
    growing = soak_report.drift(t_h, 80 + 20 * t_h + rng.normal(0, 0.5, 60), 'MB')
    assert growing['verdict'] == 'DRIFTS up' and growing['low'] < 20 < growing['high']
    assert soak_report.harmful('rss_mb.gaze_bridge', growing) and not soak_report.harmful('targets_reached', growing)
    falling = soak_report.drift(t_h, 30 - 10 * t_h + rng.normal(0, 0.5, 60), 'per row')
    assert falling['verdict'] == 'DRIFTS down' and soak_report.harmful('targets_reached', falling)
    flat = soak_report.drift(t_h, 80 + rng.normal(0, 0.5, 60), 'MB')
    assert flat['verdict'] == 'steady' and flat['low'] < 0 < flat['high']
    # Significant but below 10 % of the mean per hour: reported, not a drift.
    slight = soak_report.drift(t_h, 80 + 2 * t_h + rng.normal(0, 0.05, 60), 'MB')
    assert slight['verdict'] == 'small'
    assert soak_report.drift(t_h, np.full(60, 12.0), 'count')['verdict'] == 'steady'
    assert soak_report.drift(t_h[:2], [1.0, 2.0], 'ms')['verdict'] == 'too few rows'


# ------------------------------------------------------------------ a short run on the graph
@pytest.mark.graph
@pytest.mark.serial   # a quiet run loses nothing: a test of the other worker beside it is no quiet run
def test_a_short_soak_run_writes_every_row_figure_verdict_and_plot(tmp_path):
    out = tmp_path / 'soak'
    lines = []
    # Three rows (the fewest a drift verdict is computed from) of 4 s: every figure of a row is there by then.
    rows, results, problems = soak.run_soak(0.2, out, lines.append, row_seconds=4.0)
    assert problems == [], problems
    assert len(rows) == 3 and sum(line.startswith('[') for line in lines) == 3
    with open(out / 'soak.csv') as f:
        written = list(csv.DictReader(f))
    assert list(written[0]) == soak.COLUMNS and len(written) == 3
    for row in written:
        for col in soak.COLUMNS:
            if col not in ('warnings', 'stall', 'time_to_target_s'):
                assert row[col] != '', f'row {row["row"]}: {col} empty'
        assert math.isfinite(float(row['latency_p99_ms'])) and 0 < float(row['latency_p50_ms']) < 1000
        assert int(row['latency_samples']) > 0
        # A quiet run loses nothing on the way.
        for col in ('datagrams_lost', 'datagrams_dropped', 'commands_not_landed', 'steps_unseen',
                    'plc_watchdog_trips'):
            # The whole row and the run's lines: pytest would cut a row's repr after a few figures.
            assert float(row[col]) == 0, f'row {row["row"]}: {col} {row[col]}\n{json.dumps(row, indent=1)}\n' + \
                '\n'.join(lines) + '\n' + log_tails(out / 'logs')
        assert int(row['threads.pressure_controller']) > 1 and int(row['fds.gaze_bridge']) > 3
    assert sum(int(r['targets_reached']) for r in written) > 0
    assert not any(r['stall'] for r in rows), [r['stall'] for r in rows]
    assert set(results) >= {'latency_p50_ms', 'rss_mb.pressure_controller', 'fds.gaze_bridge',
                            'threads.plc_output', 'datagrams_lost'}
    assert all(r['verdict'] in ('steady', 'small', 'DRIFTS up', 'DRIFTS down') for r in results.values())
    md = (out / 'soak.md').read_text()
    assert '| figure | mean | slope per hour |' in md and 'rss_mb.mock_plc' in md
    assert json.loads((out / 'soak.json').read_text())['verdicts'].keys() == results.keys()
    assert (out / 'soak.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
