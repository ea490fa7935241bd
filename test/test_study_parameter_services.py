"""A study session sets parameters on pressure_controller, target_selector and wearer_sim from its
first trial on, so the simulated participant's start waits until the operator has discovered
each node's set_parameters_atomically (Operator.parameter_services_missing), on the start's deadline: a
first call on a loaded machine otherwise raced discovery and failed the session ("service
/target_selector/set_parameters_atomically is not on the graph", a bench run beside other work)."""
import pytest

from fabric_guidance.live_study.operator import STUDY_TARGET, Operator, target_position
from rosgraph import Graph, wait_until

pytestmark = pytest.mark.graph

FILES = ('params/guidance.yaml',)


def test_the_operator_names_the_parameter_services_not_yet_discovered(tmp_path):
    graph = Graph(tmp_path / 'logs')
    op = None
    try:
        graph.start('target_selector', FILES, target_names=[STUDY_TARGET], target_positions=target_position(0, 0, 1.2))
        op = Operator(graph.domain_id)
        # target_selector runs and is discovered; wearer_sim never started, so it stays missing
        wait_until(lambda: op.parameter_services_missing('target_selector', 'wearer_sim') == ['wearer_sim'], 30.0,
                   what="target_selector's parameter service discovered")
        assert op.parameter_services_missing('wearer_sim') == ['wearer_sim']
        assert op.parameter_services_missing() == []
    finally:
        if op is not None:
            op.close()
        graph.stop_all()
