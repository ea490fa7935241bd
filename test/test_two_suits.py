"""Two suits on one ROS domain: two lab graphs in the namespaces suit_a and suit_b (as two
`ros2 launch ... namespace:=` would start them), each with its own mock PLC, HoloLens stub and
target, share domain and discovery. Read from each PLC's registers over Modbus: guidance,
`enable` and `vent` of one suit never reach the other's registers (docs/interfaces.md, "Names
and namespaces"). Before the names were namespaced, both controllers answered the one `/enable`
and both plc_outputs heard the one `/pressure_command`.
"""
import socket

from diagnostic_msgs.msg import DiagnosticArray
import pytest
from std_srvs.srv import SetBool, Trigger

from fabric_guidance import interface
from fabric_guidance.core.calibration import Calibration
from fabric_guidance.core.geometry import DIRECTIONS
from rosgraph import CONFIG, Graph, Probe, free_port, fresh_domain_id, wait_until
from test_graph import P_MAX, SIM_CAL, HoloLensStub, RegisterWatch

pytestmark = pytest.mark.graph  # starts two process graphs with DDS (make flakes runs it)

LAWS = Calibration.load(CONFIG / 'calibrations' / 'sim-wearer.yaml').laws
#: Suit A's target 40 deg left, suit B's 40 deg right (immersive frame, eye height 1.2 m).
TARGETS = {'suit_a': [1.5321, 1.2856, 1.2], 'suit_b': [1.5321, -1.2856, 1.2]}
GUIDED = {'suit_a': dict.fromkeys(('L1', 'L2'), LAWS[DIRECTIONS.index('left')].pressure(40.0)),
          'suit_b': dict.fromkeys(('R1', 'R2'), LAWS[DIRECTIONS.index('right')].pressure(40.0))}
FILES = ('params/guidance.yaml', 'params/sim.yaml')
#: A service call's effect at the registers: DDS, a control step, a PLC write cycle, margin.
EFFECT_S = 5.0


class Suit:
    """One namespaced lab graph: mock PLC, plc_output, gaze_bridge, target_selector (no target
    active until next_target), pressure_controller; its HoloLens stub, register watch and probe."""

    def __init__(self, namespace: str, domain_id: int, tmp_path):
        self.namespace = namespace
        self.plc_port, gaze_port = free_port(), free_port(socket.SOCK_DGRAM)
        self.graph = Graph(tmp_path / namespace, domain_id=domain_id, namespace=namespace)
        g = self.graph
        g.start('mock_plc', FILES, port=self.plc_port)
        g.start('plc_output', FILES, plc_port=self.plc_port)
        g.start('gaze_bridge', FILES, port=gaze_port)
        g.start('target_selector', FILES, target_names=['target'], target_positions=TARGETS[namespace],
                auto_advance=False, autostart=False)
        # stall_timeout_s 0: the stub's gaze never moves (the no-progress vent is tested elsewhere).
        g.start('pressure_controller', FILES, calibration_file=SIM_CAL,
                calibration_dir=str(tmp_path / namespace / 'cal'), stall_timeout_s=0.0)
        self.hololens = HoloLensStub(gaze_port)
        self.watch = RegisterWatch(self.plc_port)
        self.probe = Probe(domain_id, f'{namespace}_operator', namespace=namespace)

    def guided(self) -> bool:
        return self.watch.matches(GUIDED[self.namespace])

    def vented(self) -> bool:
        return self.watch.matches({})

    def close(self):
        self.probe.close()
        self.hololens.close()
        self.watch.client.close()
        self.graph.stop_all()


def last_statuses(diagnostics) -> str:
    """Each node's last /diagnostics status, one line each (what a failed wait shows)."""
    last = {}
    for array in list(diagnostics):
        for status in array.status:
            last[status.name] = status
    return '\n'.join(f'{name}: {s.message} ' + ', '.join(f'{kv.key}={kv.value}' for kv in s.values)
                     for name, s in sorted(last.items()))


def test_two_namespaced_suits_on_one_domain_never_reach_each_others_registers(tmp_path):
    domain_id = fresh_domain_id()
    a = Suit('suit_a', domain_id, tmp_path)
    b = Suit('suit_b', domain_id, tmp_path)
    diagnostics = a.probe.subscribe(DiagnosticArray, interface.DIAGNOSTICS, 10)
    try:
        for suit in (a, b):
            wait_until(lambda: suit.vented(), 30.0, what=f'{suit.namespace}: its PLC up, every register at 0')
        # Each suit's services under its own names; none under the old global ones.

        def services():
            return {name for name, _ in a.probe.node.get_service_names_and_types()}
        wanted = {interface.full_name(s.name, ns) for s in interface.SERVICES for ns in ('suit_a', 'suit_b')}
        wait_until(lambda: wanted <= services(), 30.0, what=f"both suits' services on the graph: {sorted(wanted)}")
        assert not services() & set(interface.OLD_NAMES), 'a service under an old, global name'

        # A's task: A guided, B's registers untouched.
        a.probe.send(Trigger, interface.NEXT_TARGET, Trigger.Request())
        try:
            wait_until(a.guided, 30.0, what=f'suit_a guided to its target: {GUIDED["suit_a"]}')
        except AssertionError as exc:
            raise AssertionError(f'{exc}\n{last_statuses(diagnostics)}') from None
        assert b.vented() and b.watch.highest == 0.0, 'suit_a guidance reached suit_b registers'

        # A vented (its namespace's vent), then B's task: B guided, A holds its vent.
        assert a.probe.call(Trigger, interface.VENT, Trigger.Request(), attempts=3).success
        wait_until(a.vented, EFFECT_S, what='suit_a vented by its vent')
        b.probe.send(Trigger, interface.NEXT_TARGET, Trigger.Request())
        wait_until(b.guided, 30.0, what=f'suit_b guided to its target: {GUIDED["suit_b"]}')
        assert a.vented(), "suit_b's guidance moved suit_a's registers while suit_a was vented"

        # A enabled: A guides again, B goes on as it was.
        assert a.probe.call(SetBool, interface.ENABLE, SetBool.Request(data=True), attempts=3).success
        wait_until(a.guided, EFFECT_S, what="suit_a guided again after its enable")
        assert b.guided()

        # B vented: A unaffected. A disabled: B stays vented (no enable of A's reached B either).
        assert b.probe.call(Trigger, interface.VENT, Trigger.Request(), attempts=3).success
        wait_until(b.vented, EFFECT_S, what='suit_b vented by its vent')
        assert a.guided(), "suit_b's vent reached suit_a"
        assert a.probe.call(SetBool, interface.ENABLE, SetBool.Request(data=False), attempts=3).success
        wait_until(a.vented, EFFECT_S, what='suit_a vented by enable false')
        assert b.vented()
        assert max(a.watch.highest, b.watch.highest) <= P_MAX

        # /diagnostics is shared: each status names its suit's node and, as hardware_id, the device.

        def plc_status(ns):
            return next((s for m in list(diagnostics) for s in m.status if s.name == f'{ns}/plc_output: PLC output'),
                        None)
        wait_until(lambda: plc_status('suit_a') and plc_status('suit_b'), 10.0, what="both suits' plc_output status")
        assert plc_status('suit_a').hardware_id == f'PLC 127.0.0.1:{a.plc_port}'
        assert plc_status('suit_b').hardware_id == f'PLC 127.0.0.1:{b.plc_port}'
    finally:
        a.close()
        b.close()
