"""wearer_sim between two targets: the wearer faces the front in every gap, also when the gap
passed while the node was not scheduled (under load '' and the next target can come
together; before this, the ideal wearer followed the new pull from the last target's posture and
never found it). The node is driven by its callbacks directly, in a context of its own."""
import pytest
from rclpy.parameter import Parameter

from fabric_guidance.sim.wearer import gaze_from_angles


@pytest.fixture
def wearer_sim():
    import rclpy
    from rclpy.context import Context
    from fabric_guidance.graph.process_graph import fresh_domain_id
    from fabric_guidance.nodes.wearer_sim import WearerSim
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = None
    try:
        node = WearerSim(context=context, parameter_overrides=[Parameter('bridge_port', value=9)])
        yield node
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)


def active(node, name):
    from std_msgs.msg import String
    node.on_active_target(String(data=name))


def turned(node, yaw=40.0, pitch=-10.0):
    node.wearer.yaw, node.wearer.pitch = yaw, pitch


def test_a_target_that_follows_the_gap_without_a_step_between_finds_the_wearer_at_the_front(wearer_sim):
    active(wearer_sim, 'front_left')
    turned(wearer_sim)
    active(wearer_sim, '')
    active(wearer_sim, 'up_right')           # no step ran at the front in between
    assert (wearer_sim.wearer.yaw, wearer_sim.wearer.pitch) == (0.0, 0.0)


def test_a_gap_the_wearer_stepped_through_leaves_the_return_to_its_dynamics(wearer_sim):
    active(wearer_sim, 'front_left')
    turned(wearer_sim)
    active(wearer_sim, '')
    wearer_sim.step()                         # one step of the return to the front
    after_one = (wearer_sim.wearer.yaw, wearer_sim.wearer.pitch)
    active(wearer_sim, 'up_right')
    assert (wearer_sim.wearer.yaw, wearer_sim.wearer.pitch) == after_one != (0.0, 0.0)


def test_the_first_target_and_a_target_switched_directly_are_followed_from_where_the_wearer_is(wearer_sim):
    turned(wearer_sim)
    active(wearer_sim, 'front_left')          # the first: no gap before it
    assert wearer_sim.wearer.yaw == 40.0
    active(wearer_sim, 'up_right')            # switched without a gap (an operator's choice)
    assert wearer_sim.wearer.yaw == 40.0
    assert wearer_sim.wearer.gaze == pytest.approx(gaze_from_angles(40.0, -10.0))


def test_the_scene_wearer_too_faces_the_front_when_the_gap_passed_without_a_step():
    import rclpy
    from rclpy.context import Context
    from fabric_guidance.graph.process_graph import fresh_domain_id
    from fabric_guidance.nodes.wearer_sim import WearerSim
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = None
    try:
        node = WearerSim(context=context, parameter_overrides=[Parameter('bridge_port', value=9),
                                                               Parameter('scene_file', value='ideal')])
        wearer = node.scene_side.wearer
        active(node, 'ideal_3')
        wearer.torso_yaw, wearer.torso_pitch, wearer.anchor = 38.9, -21.7, (0.0, 0.0)
        active(node, '')
        active(node, 'ideal_4')
        assert (wearer.gaze_yaw, wearer.gaze_pitch, wearer.anchor) == (0.0, 0.0, None)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)


def test_a_latched_all_reader_late_to_take_them_still_gets_every_active_target_in_order():
    """What the fix rests on, checked on the middleware (Fast DDS): a reader of depth 10 keeps
    X, '' and Y published while its process took nothing; a latched reader of depth 1 keeps Y."""
    import time
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String
    from fabric_guidance.graph.process_graph import fresh_domain_id
    from fabric_guidance.nodes.qos import LATCHED_ALL_QOS, LATCHED_QOS
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = rclpy.create_node('latched_all_probe', context=context)
    try:
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        pub = node.create_publisher(String, 'active_target', LATCHED_QOS)
        every, latest = [], []
        node.create_subscription(String, 'active_target', lambda m: every.append(m.data), LATCHED_ALL_QOS)
        node.create_subscription(String, 'active_target', lambda m: latest.append(m.data), LATCHED_QOS)
        deadline = time.monotonic() + 10.0
        while (pub.get_subscription_count() < 2) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert pub.get_subscription_count() == 2
        for name in ('front_left', '', 'up_right'):
            pub.publish(String(data=name))
        deadline = time.monotonic() + 10.0
        while len(every) < 3 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert every == ['front_left', '', 'up_right']
        assert latest[-1:] == ['up_right'] and len(latest) < 3
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
