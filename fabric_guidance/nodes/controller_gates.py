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
namespace on the ROS graph. One that was alone (for ALONE_CHECKS checks, or when the operator
armed it) and sees another join drops the arm (it vents)
and reports ERROR for as long as the other is listed; one that started beside another reports
ERROR too (the graph lists a SIGKILLed process for about 20 s, so a respawn sees its dead
predecessor: it is not refused, it starts disarmed in the lab launch anyway).
"""
from __future__ import annotations


#: Checks (one a second) alone in the namespace before a process counts as the first.
ALONE_CHECKS = 3


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
        self.enabled = bool(request.data)
        if self.enabled:   # arming starts afresh (and forgets a no-progress stop)
            if self.listed_alone():
                # The operator armed this one while it was alone: it is the first, however short
                # its life so far (a second started within ALONE_CHECKS s was noticed by neither).
                self.alone_seen = True
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

    def same_name_count(self) -> int:
        """Processes of this node's name in its namespace on the graph, this one included."""
        name, ns = self.get_name(), self.get_namespace()
        return sum(1 for other, other_ns in self.get_node_names_and_namespaces() if other == name and other_ns == ns)

    def listed_alone(self) -> bool:
        return self.same_name_count() == 1

    def check_unique(self) -> None:
        name, ns = self.get_name(), self.get_namespace()
        n = self.same_name_count()
        # Alone for ALONE_CHECKS checks in a row: a process that has not discovered an older one
        # yet does not take itself for the first.
        self.alone_checks = self.alone_checks + 1 if n == 1 else 0
        if self.alone_checks >= ALONE_CHECKS:
            self.alone_seen = True
        was, self.duplicate = self.duplicate, n > 1
        if not self.duplicate:
            return
        where = f'{ns.rstrip("/")}/{name}'
        if self.alone_seen:
            self.duplicate_text = (f'another process named {where} joined: this one vents and stays disarmed (the '
                                   'operator enables once one of them is gone)')
            if self.enabled:
                self.enabled = False
                self.vent_all('another process of this name joined the namespace')
        else:
            self.duplicate_text = (f'another process named {where} is listed (live, or a killed predecessor the '
                                   'graph still lists for about 20 s)')
        if not was:
            self.get_logger().error(self.duplicate_text)
