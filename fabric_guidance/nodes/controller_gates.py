"""pressure_controller's two gates: pressure flows only while both are open.

The operator's arm (`enable` / `enable false` / `vent`): a latch. Only `enable true`, a person's
act, sets it; `enable false` and `vent` drop it, vent at once and end a running calibration; no
lifecycle transition, parameter, calibration, trial gate or restart sets it (start_enabled is
its value when the process starts: false in the lab launch, so a respawn waits for the operator).
Arming starts nothing by itself: it only lets the other gate's pressure through.

The study session's trial gate (`trial_gate`): closed for the study's rests, open for its
trials. Closing it vents; opening it never arms (the answer is not successful while the arm is
off, so the session knows at once). It is open at every start, so a graph without a session
guides as before.

Every change of either is published on /diagnostics at once (`armed`, `trial_gate`, with
`started`, the process's start time, so a client tells a restart from a vent).

One controller per namespace: every second the node counts the processes of its name in its
namespace on the ROS graph. While another is listed, an armed one drops the arm (it vents), enable
is refused, and both report ERROR: two live controllers would take turns on the same registers,
and which of them started first does not matter. A respawned process does not see its
SIGKILLed predecessor (a dead participant announces nothing to a new one; only processes that
knew it list it for its lease, about 20 s), so a respawn is not refused for it.
"""
from __future__ import annotations


class Gates:
    """Mixin of PressureController: the enable, vent and trial_gate services."""

    @property
    def flowing(self) -> bool:
        """Whether pressure may flow: the operator's arm and the session's trial gate both open."""
        return self.enabled and self.gate_open

    def on_enable(self, request, response):
        if request.data and not self.active:
            response.success = False
            response.message = f'cannot enable: the node is {self.state_label} (activate it first)'
            return response
        if request.data and self.others_listed():
            response.success = False
            response.message = f'cannot enable: {self.duplicate_text}'
            return response
        self.enabled = bool(request.data)
        if self.enabled:   # arming starts afresh (and forgets a no-progress stop)
            self.vent_controller()
            response.success = True
            response.message = 'armed' + ('' if self.gate_open else
                                          ": the study session's trial gate is closed until its next trial")
            self.gates_changed()
            return response
        # Disarming is a latch like vent: a running calibration ends and the suit vents now.
        self.vent_all('disabled by request (enable false)')
        response.success, response.message = True, 'guidance disabled (vented); call enable to guide again'
        self.gates_changed()
        return response

    def on_vent(self, request, response):
        self.enabled = False
        self.vent_all('vented by request')
        response.success, response.message = True, 'vented; call enable to guide again'
        self.gates_changed()
        return response

    def on_trial_gate(self, request, response):
        self.gate_open = bool(request.data)
        if not self.gate_open:
            self.vent_all('trial gate closed')
            response.success, response.message = True, 'trial gate closed (vented)'
        elif not self.enabled:
            response.success = False
            response.message = ("trial gate open, but the operator's arm is off (a vent, enable false or a restart): "
                                'nothing flows until the operator calls enable')
        else:
            self.vent_controller()   # the trial begins from the gaze at that moment
            response.success, response.message = True, 'trial gate open'
        self.gates_changed()
        return response

    def gates_changed(self) -> None:
        """Tell the graph now (not at the next diagnostics period): a session stops its trial on it."""
        self.publish_diagnostics()

    def on_second(self) -> None:
        """The diagnostics timer: the uniqueness check, then the diagnostics."""
        self.check_unique()
        self.publish_diagnostics()

    def others_listed(self) -> bool:
        """Whether the graph lists another process of this node's name in its namespace (and
        the ERROR text that says so)."""
        name, ns = self.get_name(), self.get_namespace()
        n = sum(1 for other, other_ns in self.get_node_names_and_namespaces() if other == name and other_ns == ns)
        if n > 1:
            self.duplicate_text = (f'another process named {ns.rstrip("/")}/{name} is listed: this one is '
                                   'vented and disarmed, and enable is refused, until only one is left')
        return n > 1

    def check_unique(self) -> None:
        was, self.duplicate = self.duplicate, self.others_listed()
        if not self.duplicate:
            return
        if self.enabled:
            self.enabled = False
            self.vent_all('another process of this name is listed in the namespace')
        if not was:
            self.get_logger().error(self.duplicate_text)
