"""The replay's guard (bag/player.py LiveGuard) on a graph described by hand: which subscribers
make a namespace live, and that a subscriber the graph has not named yet is waited for."""
from types import SimpleNamespace

import pytest

from fabric_guidance.bag.player import LiveGraphError, LiveGuard
from fabric_guidance.bag.topics import is_control_topic


class FakeGraph:
    """What LiveGuard asks of its node: the nodes, and each topic's subscribers."""

    def __init__(self, nodes=(), subscribers=None):
        self.nodes, self.subscribers = list(nodes), subscribers or {}

    def get_node_names_and_namespaces(self):
        return self.nodes

    def get_subscriptions_info_by_topic(self, topic):
        return [SimpleNamespace(node_name=n, node_namespace=ns) for n, ns in self.subscribers.get(topic, [])]


def guard(graph, topics, sim_time=None):
    g = LiveGuard(graph, topics)
    g._sim_time.update(sim_time or {})   # the controllers' use_sim_time, as their parameter service says
    return g


def test_control_topics_are_the_ones_that_move_a_suit():
    assert all(is_control_topic(t) for t in ('/gaze', '/suit_a/target', '/active_target', '/pressure_command',
                                             '/replay/head_pose', '/confirm', '/live_targets/microbead'))
    assert not any(is_control_topic(t) for t in ('/diagnostics', '/speech', '/controller_parameters', '/clock'))


def test_a_controller_on_the_wall_clock_or_a_plc_output_makes_the_namespace_live():
    wall = FakeGraph(subscribers={'/gaze': [('pressure_controller', '/')]})
    with pytest.raises(LiveGraphError, match='/gaze: /pressure_controller runs on the wall clock'):
        guard(wall, ['/gaze'], {'/pressure_controller': False}).check()
    driven = FakeGraph(nodes=[('plc_output', '/suit_a')])
    with pytest.raises(LiveGraphError, match='/suit_a/target: /suit_a/plc_output drives a suit there'):
        guard(driven, ['/suit_a/target']).check()
    command = FakeGraph(subscribers={'/pressure_command': [('plc_output', '/')]})
    with pytest.raises(LiveGraphError, match='--namespace replay'):
        guard(command, ['/pressure_command']).check()


def test_a_controller_of_its_own_or_another_namespace_is_not_live():
    graph = FakeGraph(nodes=[('plc_output', '/'), ('pressure_controller', '/')],
                      subscribers={'/replay/gaze': [('pressure_controller', '/replay'), ('bag_recorder', '/')]})
    g = guard(graph, ['/replay/gaze', '/clock', '/diagnostics'], {'/replay/pressure_controller': True})
    assert g.topics == ['/replay/gaze']
    g.check()


def test_a_subscriber_not_named_yet_is_waited_for_then_refused():
    graph = FakeGraph(subscribers={'/gaze': [('_NODE_NAME_UNKNOWN_', '_NODE_NAMESPACE_UNKNOWN_')]})
    g = guard(graph, ['/gaze'])
    assert g.look() == '/gaze'
    with pytest.raises(LiveGraphError, match="a subscriber's node is not known"):
        g.wait_known(0.1)
    graph.subscribers['/gaze'] = [('pressure_controller', '/')]   # named: a live one
    with pytest.raises(LiveGraphError, match='runs on the wall clock'):
        guard(graph, ['/gaze'], {'/pressure_controller': False}).wait_known(1.0)


def test_while_playing_a_subscriber_unnamed_for_a_moment_is_waited_for_one_unnamed_for_wait_s_refused():
    """A fresh run's replay stopped at its second loop: the graph had lost a subscriber's name for
    a moment (a loaded machine). While playing, the guard gives a name wait_s, as at the start."""
    import time
    named = [('pressure_controller', '/replay')]
    graph = FakeGraph(subscribers={'/replay/gaze': named})
    g = guard(graph, ['/replay/gaze'], {'/replay/pressure_controller': True})
    g.check(0.05)
    graph.subscribers['/replay/gaze'] = [('_NODE_NAME_UNKNOWN_', '_NODE_NAMESPACE_UNKNOWN_')]
    g.check(0.05)                       # unnamed just now: not refused yet
    graph.subscribers['/replay/gaze'] = named
    g.check(0.05)                       # named again: the wait starts afresh next time
    graph.subscribers['/replay/gaze'] = [('_NODE_NAME_UNKNOWN_', '_NODE_NAMESPACE_UNKNOWN_')]
    g.check(0.05)
    time.sleep(0.06)                    # unnamed for longer than wait_s
    with pytest.raises(LiveGraphError, match="a subscriber's node is not known"):
        g.check(0.05)
    graph.subscribers['/replay/gaze'] = [('pressure_controller', '/')]   # a live one: at once
    with pytest.raises(LiveGraphError, match='runs on the wall clock'):
        guard(graph, ['/replay/gaze'], {'/pressure_controller': False}).check(10.0)
