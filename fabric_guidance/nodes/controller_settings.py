"""pressure_controller's parameters at run time: each change takes effect at once, as the table
(core/controller_parameters.py, `live`) says, or is refused with the reason. None is accepted
and ignored: a read-only one is refused by rcl, a live one is applied here, checked in full
before anything changes (several in one call: all or none)."""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult

from ..core import Calibration, condition
from ..core.controller_parameters import BY_NAME, CALIBRATION, check
from ..core.safe_input import check_wearer


class LiveParameters:
    """Mixin of PressureController: its on-set-parameters callback."""

    def on_set_parameters(self, params) -> SetParametersResult:
        """Each change takes effect now (core/controller_parameters.py's `live`) or is refused with
        the reason; several in one call are applied together or not at all."""
        if self._declaring:
            return SetParametersResult(successful=True)
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
        if p_max > self.ceiling_kpa:
            return (f'p_max_kpa {p_max:g} kPa is above the ceiling {self.ceiling_kpa:g} kPa, the value the node '
                    'started with (the PLC clamps to its register map too)')
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
        elif 'wearer' in changed and (self.calibration is None or self.calibration.wearer != values['wearer']):
            # Another person: never guided with someone else's fit; their own file if they have one.
            own = self.cal_dir_of(values['calibration_dir']) / f'{values["wearer"]}.yaml'
            calibration = Calibration.load(own) if own.is_file() else None
            loaded = str(own) if calibration is not None else 'none'
        setup = controller = None
        if self.channel_map is not None:
            setup = self.make_setup(calibration, values)
            controller = setup.make_controller()   # the core's checks, before anything changes
        # Everything checked: commit.
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
