"""The guided lab the fault tests share (test_faults_process.py, test_plc_program_graph.py):
plc_output, gaze_bridge, target_selector with one target 40 deg left, pressure_controller on
the simulated wearer's calibration; a HoloLens stub sending to the bridge and a watch on the
PLC's registers. Each test file adds its PLC (mock_plc, or the PLC program behind a proxy)."""
import contextlib

from rosgraph import Graph
from test_graph import F_LEFT_40, SIM_CAL, HoloLensStub, RegisterWatch

FILES = ('params/guidance.yaml', 'params/sim.yaml')
#: The channels guidance to the target drives, and their pressure [kPa].
GUIDED = {'L1': F_LEFT_40, 'L2': F_LEFT_40}


def guided_overrides(log_dir, output_port: int, gaze_port: int) -> dict:
    """Parameters of the four lab nodes; plc_output talks to output_port."""
    return {
        'plc_output': dict(plc_port=output_port),
        'gaze_bridge': dict(port=gaze_port),
        'target_selector': dict(target_names=['left40'], target_positions=[1.5321, 1.2856, 1.2],
                                auto_advance=False),
        # stall_timeout_s 0: the stub's gaze never moves, and the no-progress vent (tested in
        # test_node_pressure_controller) would end the guidance these faults interrupt.
        'pressure_controller': dict(calibration_file=str(SIM_CAL),
                                    calibration_dir=str(log_dir / 'cal'), stall_timeout_s=0.0),
    }


class GuidedLab:
    """Set graph, plc_port, gaze_port and overrides (node -> parameters, in start order), then
    call start_all()."""

    graph: Graph
    overrides: dict

    def start_all(self, stub=HoloLensStub) -> None:
        for node in self.overrides:
            self.start(node)
        self.hololens = stub(self.gaze_port)
        self.watch = RegisterWatch(self.plc_port)

    def start(self, node):
        return self.graph.start(node, FILES, **self.overrides[node])


@contextlib.contextmanager
def guided_until_closed(lab, log, title: str):
    """A module's lab: guided (the graph up), then closed and its worst times reported."""
    try:
        lab.guided(what='the graph up')
        yield lab
    finally:
        lab.close()
        log.report(title)
