"""Throughput: the headless simulation's speed over real time for the paper's speed protocol
(one core, simulated seconds per wall second, Algorithm 1 included)."""
from __future__ import annotations


def headless_speedup(subjects: int = 1, repetitions: int | None = None) -> dict:
    from ..sim.protocols import run_protocol
    from ..sim.scene import load_scene
    scene = load_scene('paper-speed')
    if repetitions is not None:
        scene = scene.replace(repetitions=repetitions)
    results = run_protocol(scene, subjects, workers=1)
    return {'speedup': results.sim_s / results.wall_s, 'simulated_s': results.sim_s, 'wall_s': results.wall_s,
            'subjects': subjects, 'trials': len(results)}
