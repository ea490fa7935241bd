"""pressure_controller's parameters at run time: each change takes effect at once, as the table
(core/controller_parameters.py, `live`) says, or is refused with the reason. None is accepted
and ignored: a read-only one is refused by rcl, a live one is applied here, checked in full
before anything changes (several in one call: all or none).

The safety limits (controller_parameters.LIMITS) only tighten at run time: a change that would
loosen one is refused with the reason, a tightening applies at once and is held across restarts
(held_limits.py); use_sim_time is fixed while the node runs (FIXED_AT_RUN_TIME)."""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter as RosParameter

from ..core import Calibration, condition
from ..core.controller_parameters import (BY_NAME, CALIBRATION, FIXED_AT_RUN_TIME, LIMITS, check, default, loosens,
                                          tightest)
from ..core.safe_input import check_wearer
from .held_limits import limits_file, read_held, write_held


class LiveParameters:
    """Mixin of PressureController: its on-set-parameters callback."""

    def on_set_parameters(self, params) -> SetParametersResult:
        """Each change takes effect now (core/controller_parameters.py's `live`) or is refused with
        the reason; several in one call are applied together or not at all."""
        if self._declaring:
            return SetParametersResult(successful=True)
        for p in params:
            if p.name in FIXED_AT_RUN_TIME and p.value != self.get_parameter(p.name).value:
                self.get_logger().warning(f'parameter {p.name} refused: {FIXED_AT_RUN_TIME[p.name]}')
                return SetParametersResult(successful=False, reason=FIXED_AT_RUN_TIME[p.name])
        changed = {p.name: p.value for p in params if p.name in BY_NAME and p.value != self.v.get(p.name)}
        try:
            why = self.apply_parameters(changed) if changed else ''
        except (ValueError, OSError) as exc:   # a file's or the core's check: one line, naming it
            why = ' '.join(str(exc).split())
        if why:
            self.get_logger().warning(f'parameters {sorted(changed)} refused: {why}')
            return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    def apply_parameters(self, changed: dict) -> str:
        """Apply `changed` at once; the reason for refusing it ('' applied)."""
        for name, value in changed.items():
            if BY_NAME[name].read_only:
                return f'{name} is read-only: it cannot change while the node runs'
            changed[name] = check(name, value, f'parameter "{name}"')
        p_max = changed.get('p_max_kpa', self.p_max)
        for name in LIMITS:
            if name in changed and loosens(name, self.v[name], changed[name]):
                held = f', held since a run-time tightening ({self.limits_path})' if name in self.held else ''
                return (f'{name} {changed[name]:g} would loosen a safety limit (in force: {self.v[name]:g}{held}); '
                        'limits only tighten at run time: a person loosens one by stopping the controller, '
                        'removing the held limit and starting it again (docs/safety.md)')
        if self.procedure is not None:
            busy = [n for n in changed if n not in ('p_max_kpa', 'speak')]
            if busy or p_max > self.p_max:
                return (f'a calibration is running: {", ".join(busy) or "raising p_max_kpa"} refused until it ends '
                        '(vent ends it; a lower p_max_kpa ends it too)')
        values = {**self.v, **changed}
        if 'wearer' in changed:
            check_wearer(changed['wearer'], 'parameter "wearer"')
        new_condition = condition(values['condition'])
        layout = new_condition.layout or 'suit'
        if self.channel_map is not None and layout not in self.channel_map.layouts:
            return (f'condition {new_condition.number} needs the layout "{layout}", which the channel map does not '
                    f'have (it has {list(self.channel_map.layouts)})')
        calibration, loaded = self.calibration, ''
        if 'calibration_file' in changed:
            calibration, loaded = self.read_calibration(values['calibration_file']), values['calibration_file']
            self.same_person(calibration, values['wearer'], values['calibration_file'])
        elif 'wearer' in changed and (self.calibration is None or self.calibration.wearer != values['wearer']):
            # Another person: never guided with someone else's fit; their own file if they have one.
            own = self.cal_dir_of(values['calibration_dir']) / f'{values["wearer"]}.yaml'
            calibration = Calibration.load(own) if own.is_file() else None
            loaded = str(own) if calibration is not None else 'none'
        setup = controller = None
        if self.channel_map is not None:
            setup = self.make_setup(calibration, values)
            controller = setup.make_controller()   # the core's checks, before anything changes
        # Everything checked: hold the tightened limits first (a death right after keeps them), then commit.
        tightened = {n: changed[n] for n in LIMITS if n in changed}
        if tightened:
            self.hold_limits(tightened)
        self.v.update(changed)
        if self.procedure is not None:
            self.end_calibration(f'p_max_kpa lowered to {p_max:g} kPa')
        quiet = set(changed) <= {'speak', 'calibration_dir'} | {p.name for p in CALIBRATION}
        if setup is not None and not quiet:
            self.calibration, self.setup, self.controller = calibration, setup, controller
            if 'control_rate_hz' in changed:
                self.start_timer()
            if 'condition' in changed:
                self.speech_due = new_condition.speech and self.target is not None
            self.vent_all('parameters changed')   # zeros now, at the new limit and layout
            self.publish_parameters(self.step_count)   # the next step runs with them
        self.get_logger().info('set ' + ', '.join(f'{k} = {v!r}' for k, v in changed.items())
                               + (f'; calibration: {loaded}' if loaded else ''))
        return ''

    # ---- the held limits (held_limits.py)
    def load_held_limits(self) -> None:
        """At start: each safety limit in force is the tighter of its parameter and its held value;
        the parameter shows the value in force. A file that cannot be read stops the start-up."""
        self.limits_path = limits_file(self.v['state_dir'], self.get_namespace())
        self.held = read_held(self.limits_path)
        self.held_text = ''
        overridden = {}
        for name, value in self.held.items():
            if tightest(name, value, self.v[name]) == value and value != self.v[name]:
                overridden[name] = (value, self.v[name])
        if overridden:
            self.set_parameters([RosParameter(n, value=v) for n, (v, _) in overridden.items()])
            for name, (value, _) in overridden.items():
                self.v[name] = value
            self.held_text = ', '.join(f'{n} {v:g} (parameter {p:g})' for n, (v, p) in overridden.items())
            self.get_logger().warning(f'held limits from {self.limits_path}: {self.held_text}; a person lifts them '
                                      '(docs/safety.md)')

    def hold_limits(self, tightened: dict) -> None:
        """Write the tightened limits to the state file; a failure is logged and shown in the
        diagnostics (the tightening applies anyway: refusing it would be the less safe answer)."""
        held = {**self.held, **tightened}
        try:
            write_held(self.limits_path, held)
            self.held, self.hold_error = held, ''
        except OSError as exc:
            self.held = held
            self.hold_error = f'not held across a restart: {exc}'
            self.get_logger().error(f'limits {sorted(tightened)} applied but {self.hold_error}')
        self.held_text = ', '.join(f'{n} {v:g}' for n, v in self.held.items())

    @staticmethod
    def same_person(calibration, wearer: str, cal_file: str) -> None:
        """ValueError when a calibration names another person than `wearer` (the default, unnamed
        `wearer` takes the file's): one person's calibration never guides another."""
        if calibration is None or wearer == default('wearer') or calibration.wearer == wearer:
            return
        raise ValueError(f'calibration file {cal_file}: field "wearer" is "{calibration.wearer}", the parameter '
                         f'"wearer" is "{wearer}": one person\'s calibration never guides another (set wearer to '
                         f'the file\'s, or give {wearer}\'s own file)')
