"""The scene simulator's closed loop built as the pressure_controller node builds it: NodeLoop,
a sim.engine.ClosedLoop subclass that (a) builds the controller as the node does, with the
wearer's own gain when asked (use_wearer_gain) and follow_target (follow_moving_target), and (b)
gives the controller the target of the moment at every control step (move_target(): the node
receives the target's position on every message). With a static target, and with the paper's
defaults, NodeLoop runs exactly as ClosedLoop (test_beyond checks both). The per-wearer gain
study (per_wearer_gain.py) and the moving-target study (moving_targets.py) run on it.
"""
from __future__ import annotations

from typing import Sequence

from ..core.calibration import Calibration
from ..core.control_step import controller_gain
from ..core.feedback import step_directions
from ..core.geometry import wrap_deg
from .engine import ClosedLoop, scene_controller


class NodeLoop(ClosedLoop):
    """ClosedLoop whose controller is built as the pressure_controller node builds it and is
    given the target of the moment at each control step.

    use_wearer_gain: G is the calibration's adjustment_gain when it has one (the node's
    use_wearer_gain), else the scene's. follow_target: core.feedback's follow_target (the node's
    follow_moving_target). live_target: the controller reads the current target (moved with
    move_target()) at every control step, as the node does; False is the engine's (and the
    paper's) law, theta_t taken once when guidance begins. Default: live exactly when
    follow_target.
    """

    def __init__(self, scene, wearer, run: Sequence[int], condition: int | None = None,
                 calibration: Calibration | None = None, *, use_wearer_gain: bool = False,
                 follow_target: bool = False, live_target: bool | None = None, channel_map=None):
        super().__init__(scene, wearer, run, condition, calibration, channel_map)
        self.follow_target = bool(follow_target)
        self.live_target = self.follow_target if live_target is None else bool(live_target)
        self.gain = controller_gain(scene.controller.gain, use_wearer_gain, calibration)
        if self.controller is not None:
            # As ClosedLoop builds it (and as the node does), with the gain and the option.
            self.controller = scene_controller(scene.controller, self.cond.mode, calibration,
                                               use_wearer_gain=use_wearer_gain,
                                               follow_target=self.follow_target)

    def move_target(self, yaw: float, pitch: float) -> None:
        """The active target is now at (yaw, pitch): no vent, no new guidance (the node's
        on_target for the target it is already guiding to). The eyes see it there at once."""
        if self.target is None:
            raise RuntimeError('move_target() needs an active target: present() one first')
        self.target = (float(yaw), float(pitch))

    def _control(self, t: float) -> None:
        if not self.live_target or self.procedure is not None:
            super()._control(t)
            return
        gaze = self._guidance_gaze(t)
        if gaze is None:
            return
        gy, gp, _ = gaze
        y0, p0 = self._g0
        # GuidanceController.update's angles, from g0, with the target of this moment; every
        # direction is stepped (a direction whose theta_t is <= 0 resets, as in update()).
        self._theta_t = (wrap_deg(self.target[0] - y0), self.target[1] - p0)
        self._set_command(step_directions(self.controller.directions, *self._theta_t, wrap_deg(gy - y0),
                                          gp - p0, t))


__all__ = ['NodeLoop']
