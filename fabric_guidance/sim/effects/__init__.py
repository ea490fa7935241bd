"""The effects a scene can switch on, one small class each, and the registry of their names.

A scene lists the effects it wants (config/scenes/*.yaml, key `effects:`); the engine builds
exactly those, fresh for every run, and composes them at fixed places of the closed loop:

    controller --(command, per direction = mean of its channels)--> [pressure] regulator_lag,
    suit_hysteresis --(pressure the suit exerts)--> [percept] weber_perception --> [delay]
    reaction_delay --> wearer's goal --> [body] body_dynamics --> true gaze --> [gaze]
    gaze_noise, datagram_loss, datagram_latency --> the controller's last gaze sample
    condition 4: phrase --> [speech] speech_latency --> [delay] reaction_delay --> goal
    [cue] cue_misreading, surface_resistance, relative_perception: how the wearer reads the
    haptic cue (its direction and size) and when they read it again
    [view] hololens_view: when a visible target is seen, found among the dummies, confirmed

With no effect listed the wearer is ideal: the suit exerts the command at once, the wearer
perceives it exactly, at once, and stands at the goal it means; the controller sees the true
gaze every step.

Pressure-side effects act per channel in the real suit. They act identically on every channel,
and all channels of one direction carry the same command (core.channels.ChannelMap), so they
are simulated once per direction: the mean over the direction's channels that the wearer feels
is the same number (test_sim_effects checks it against an 18-channel simulation).

Randomness: each stochastic effect owns numpy Generators derived from the scene seed, its own
name, the wearer index and the run (numpy SeedSequence spawn keys, see `RunContext`), and it
draws a fixed number of values per step or per event whatever the other effects do. So adding,
removing or re-parametrising one effect never changes another effect's random numbers.

Every parameter's default says where it comes from: the paper, the package's own mock
hardware, an order of magnitude from datasheets, or a human-factors figure. Where a value is an
assumption the docstring says so plainly.

One module per stage (pressure, perception, body, gaze_stream, speech_latency, cue,
hololens_view) on base (streams, run context, parameter checks, Effect); the registry is here.
"""
from __future__ import annotations

from .base import STAGES, Draws, Effect, EffectError, RunContext, generator, seed_sequence, stream_key
from .pressure import RegulatorLag, SuitHysteresis
from .perception import ReactionDelay, WeberPerception
from .body import BodyDynamics
from .gaze_stream import DatagramLatency, DatagramLoss, GazeNoise
from .speech_latency import SpeechLatency
from .cue import CueMisreading, RelativePerception, SurfaceResistance
from .hololens_view import HOLOLENS2_FOV_DEG, HololensView

REGISTRY: dict[str, type[Effect]] = {cls.name: cls for cls in (
    GazeNoise, DatagramLoss, DatagramLatency, RegulatorLag, SuitHysteresis, WeberPerception, ReactionDelay,
    BodyDynamics, SpeechLatency, CueMisreading, SurfaceResistance, RelativePerception,
    HololensView)}


def effect_class(name: str) -> type[Effect]:
    """The class registered under `name`; EffectError listing the valid names otherwise."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise EffectError(f'unknown effect {name!r}; valid effects: {", ".join(sorted(REGISTRY))}') from None


def make_effect(name: str, params: dict | None = None) -> Effect:
    """Build an effect from its name and parameters; unknown parameters are errors naming
    the parameter and listing the valid ones."""
    cls = effect_class(name)
    params = dict(params or {})
    valid = cls.parameters()
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise EffectError(f'{name}: unknown parameter(s) {unknown}; valid: '
                          + ', '.join(f'{k} ({u}, default {d})' for k, (d, u) in valid.items()))
    return cls(**params)


def by_stage(effects) -> dict[str, list[Effect]]:
    """Effects grouped by stage, each stage in the registry's physical order."""
    out: dict[str, list[Effect]] = {s: [] for s in STAGES}
    for e in effects:
        out[e.stage].append(e)
    for s in STAGES:
        out[s].sort(key=lambda e: e.order)
    return out


def start_effects(specs, ctx: RunContext, wearer_params: dict | None = None
                  ) -> tuple[list[Effect], dict[str, list[Effect]]]:
    """A run's effects built from the scene's specs and started with its context: (the effects
    in the scene's order, by_stage() of them). wearer_params: effect -> {parameter: value} of
    this wearer's own traits (population.WearerSpec.effect_params), over the scene's values.
    The engine and the graph's wearer both start them so, which keeps their seeding the same."""
    wearer_params = wearer_params or {}
    effects = [spec.build(wearer_params.get(spec.name)) for spec in specs]
    for e in effects:
        e.start(ctx)
    return effects, by_stage(effects)


__all__ = ['HOLOLENS2_FOV_DEG', 'REGISTRY', 'STAGES', 'BodyDynamics', 'CueMisreading',
           'HololensView',
           'RelativePerception', 'SurfaceResistance', 'DatagramLatency', 'DatagramLoss', 'Draws',
           'Effect', 'EffectError',
           'GazeNoise', 'ReactionDelay', 'RegulatorLag', 'RunContext', 'SpeechLatency', 'SuitHysteresis',
           'WeberPerception', 'by_stage', 'effect_class', 'generator', 'make_effect', 'seed_sequence',
           'start_effects', 'stream_key']
