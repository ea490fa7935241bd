"""A scene of the headless simulator through the real ROS graph: `fabric-guidance demo --scene`
(fabric_guidance.commands.demo.run_demo(scene=...)) and wearer_sim with scene_file.

The demos run as separate processes on their own ROS domain (as `make demo` does); the
wearer_sim test binds the UDP socket the node sends its gaze datagrams to.
"""
import json
import math
from pathlib import Path
import re
import select
import socket
import subprocess
import sys
import time

import pytest

from fabric_guidance.sim.effects import GazeNoise, RunContext
from fabric_guidance.sim.engine import trial_run
from fabric_guidance.sim.scene import load_scene
from rosgraph import CONFIG, ROOT, Graph, wait_until

pytestmark = pytest.mark.graph  # starts a process graph with DDS

SCENES = CONFIG / 'scenes'
P_MAX = 375.0
WEARER_EFFECTS = ('suit_hysteresis', 'weber_perception', 'reaction_delay', 'body_dynamics', 'gaze_noise',
                  'datagram_loss', 'datagram_latency')


def run_scene_demo(scene: Path, out: Path, timeout_s: float = 40.0) -> tuple[subprocess.CompletedProcess, float]:
    """run_demo(scene=...) in its own process, as the CLI will call it; (result, seconds)."""
    code = ('import sys; from fabric_guidance.commands.demo import run_demo; '
            'sys.exit(run_demo(scene=sys.argv[1], out_dir=sys.argv[2], timeout_s=float(sys.argv[3])))')
    t0 = time.monotonic()
    out_proc = subprocess.run([sys.executable, '-c', code, str(scene), str(out), str(timeout_s)],
                              capture_output=True, text=True, timeout=120, cwd=ROOT)
    return out_proc, time.monotonic() - t0


def found_of(stdout: str) -> tuple[int, int]:
    m = re.search(r'^(\d+) of (\d+) targets found', stdout, re.M)
    assert m, stdout
    return int(m.group(1)), int(m.group(2))


def highest_command(stdout: str) -> float:
    m = re.search(r'highest command ([\d.]+) kPa', stdout)
    assert m, stdout
    return float(m.group(1))


def assert_nothing_left(out: Path) -> None:
    # pressure_controller carries the demo's folder in its arguments (calibration_file).
    leftovers = subprocess.run(['pgrep', '-f', str(out)], capture_output=True, text=True).stdout
    assert not leftovers.strip(), f'processes left behind: {leftovers}'


def test_demo_ideal_scene_finds_every_target(tmp_path):
    out, elapsed = run_scene_demo(SCENES / 'ideal.yaml', tmp_path)
    print(out.stdout)
    assert out.returncode == 0, out.stdout + out.stderr
    assert found_of(out.stdout) == (4, 4)
    assert 'after shutdown the PLC registers read 0.0 kPa at most' in out.stdout
    assert highest_command(out.stdout) <= P_MAX
    assert 'scene ideal: no effect listed' in out.stdout
    # The calibration by Algorithm 1 (headless, before the graph) went to pressure_controller.
    cal = tmp_path / 'ideal-S01.yaml'
    assert cal.is_file()
    assert str(cal) in (tmp_path / 'pressure_controller.log').read_text()
    print(f'demo took {elapsed:.1f} s')   # its own --timeout bounds it; speed belongs to make bench
    assert_nothing_left(tmp_path)


def test_demo_paper_speed_scene_runs_with_its_effects(tmp_path):
    out, elapsed = run_scene_demo(SCENES / 'paper-speed.yaml', tmp_path)
    print(out.stdout)
    assert out.returncode in (0, 1), out.stdout + out.stderr      # 1: a target not found in time
    assert 'exited early' not in out.stdout
    # The effects named, and where the graph realises them.
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith('scene paper-speed: effects realised'))
    assert 'mock_plc: regulator_lag (regulator_tau_s 0.15 s)' in line
    wearer_part = line.split('wearer_sim: ')[1].split(';')[0]
    assert wearer_part.split(', ') == list(WEARER_EFFECTS)
    assert 'unused in condition 1: speech_latency' in line
    assert 'regulator tau 0.15 s' in (tmp_path / 'mock_plc.log').read_text()
    log = (tmp_path / 'wearer_sim.log').read_text()
    assert 'scene paper-speed' in log and f'effects applied here: {", ".join(WEARER_EFFECTS)}' in log
    # What must hold whatever the effects do: progress, the limit, vented at the end.
    found, total = found_of(out.stdout)
    assert total == 4 and found >= 1
    assert highest_command(out.stdout) <= P_MAX
    m = re.search(r'mock PLC: largest value ever written ([\d.]+) kPa', out.stdout)
    assert m and float(m.group(1)) <= P_MAX + 0.01, out.stdout   # register resolution
    assert 'after shutdown the PLC registers read 0.0 kPa at most' in out.stdout
    print(f'demo took {elapsed:.1f} s')   # its own --timeout bounds it; speed belongs to make bench
    assert_nothing_left(tmp_path)


def test_demo_refuses_a_bad_scene(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text((SCENES / 'ideal.yaml').read_text().replace('effects: []', 'effects: [gaze_nois]'))
    out, _ = run_scene_demo(bad, tmp_path / 'out')
    assert out.returncode == 2
    assert "unknown effect 'gaze_nois'" in out.stdout


class GazeCatcher:
    """A UDP socket where a wearer_sim sends its datagrams."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(('127.0.0.1', 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.datagrams: list[dict] = []

    def drain(self) -> None:
        while select.select([self.sock], [], [], 0)[0]:
            self.datagrams.append(json.loads(self.sock.recv(4096)))

    def close(self):
        self.sock.close()


def yaw_pitch(d: dict) -> tuple[float, float]:
    """The datagram's gaze direction (Unity frame: x right, y up, z forward) as yaw (positive
    left) and pitch (positive up), degrees."""
    x, y, z = d['gaze_direction']
    return math.degrees(math.atan2(-x, z)), math.degrees(math.atan2(y, math.hypot(x, z)))


def test_wearer_sim_alone_sends_the_scenes_gaze_noise(tmp_path):
    """Alone (no PLC, no target) the scene wearer stands facing front. With paper-speed's
    gaze_noise the directions vary, and datagram seq k carries the k-th noise draw of the
    engine's stream for (scene seed, wearer 0, trial_run(1, 0)); with the ideal scene every
    datagram is the same, and none is missing."""
    noisy, clean = GazeCatcher(), GazeCatcher()
    graphs = [Graph(tmp_path / 'noisy'), Graph(tmp_path / 'clean')]
    try:
        graphs[0].start('wearer_sim', ('params/guidance.yaml', 'params/sim.yaml'), bridge_port=noisy.port,
                        scene_file=str(SCENES / 'paper-speed.yaml'), wearer_index=0)
        graphs[1].start('wearer_sim', ('params/guidance.yaml', 'params/sim.yaml'), bridge_port=clean.port,
                        scene_file=str(SCENES / 'ideal.yaml'), wearer_index=0)

        def enough():
            noisy.drain()
            clean.drain()
            return len(noisy.datagrams) >= 90 and len(clean.datagrams) >= 90
        wait_until(enough, 40.0, interval=0.05, what='90 datagrams from each wearer_sim')
        for g in graphs:
            assert g.stop('wearer_sim') == 0
    finally:
        for g in graphs:
            g.stop_all()
        noisy.close()
        clean.close()

    # Without noise: identical directions, consecutive sequence numbers from 1.
    assert {tuple(d['gaze_direction']) for d in clean.datagrams} == {tuple(clean.datagrams[0]['gaze_direction'])}
    assert yaw_pitch(clean.datagrams[0]) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert [d['seq'] for d in clean.datagrams] == list(range(1, len(clean.datagrams) + 1))

    # With noise: the directions vary by about sd_deg = 1.
    angles = [yaw_pitch(d) for d in noisy.datagrams]
    yaws = [a[0] for a in angles]
    spread = math.sqrt(sum(y * y for y in yaws) / len(yaws))
    assert len({tuple(d['gaze_direction']) for d in noisy.datagrams}) > 0.9 * len(noisy.datagrams)
    assert 0.5 < spread < 2.0, spread
    # ... and they are the engine's draws: sample k gets draws 2(k-1), 2k-1 of gaze_noise's stream.
    scene = load_scene(SCENES / 'paper-speed.yaml')
    noise = scene.effect('gaze_noise').build()
    assert isinstance(noise, GazeNoise)
    noise.start(RunContext(1.0 / 60.0, scene.seed, 0, trial_run(1, 0)))
    seqs = [d['seq'] for d in noisy.datagrams]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)   # latency never reorders what is sent
    expected = {}
    for k in range(1, max(seqs) + 1):
        expected[k] = noise.gaze(0.0, (k, 0.0, 0.0, 0.0))[2:]
    for d, (yaw, pitch) in zip(noisy.datagrams, angles):
        assert (yaw, pitch) == pytest.approx(expected[d['seq']], abs=1e-9), d['seq']
    # Some samples never arrive (datagram_loss; datagram_latency passes on the newest per step).
    assert max(seqs) > len(seqs)
