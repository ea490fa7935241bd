"""The labels of the package's Float64MultiArrays (docs/interfaces.md, "Array labels"): one 1-D
layout dimension whose label names the values in data order; the bag code reads labelled and
unlabelled (older) arrays alike. The nodes' arrays on the wire: test_node_pressure_controller.py
and test_node_plc.py; in a recorded bag: test_bag_record.py."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from fabric_guidance.bag.controller_io import FIELDS, INPUT_SIZE
from fabric_guidance.bag.offline import float64_array
from fabric_guidance.core.channels import ChannelMap, ChannelMapError, label_names, layout_label
from fabric_guidance.nodes.array_layout import named_layout
from fabric_guidance.paths import config_path

CHANNELS = ChannelMap.load(config_path('hardware/channel_map.yaml')).channels


@pytest.mark.parametrize('names', [CHANNELS, FIELDS, ('x',)])
def test_a_label_gives_back_its_names_in_order(names):
    label = layout_label(names)
    assert label_names(label) == tuple(names)
    layout = named_layout(names)
    assert len(layout.dim) == 1 and layout.data_offset == 0
    dim = layout.dim[0]
    assert dim.label == label and dim.size == dim.stride == len(names)


def test_the_layout_is_a_1d_array_of_the_values():
    # A reader that reshapes by the dimension sizes (as generic MultiArray helpers do) gets
    # the values back in their order.
    msg = Float64MultiArray(layout=named_layout(CHANNELS), data=[float(i) for i in range(len(CHANNELS))])
    shape = [d.size for d in msg.layout.dim]
    values = np.asarray(msg.data).reshape(shape)
    assert values.shape == (len(CHANNELS),)
    assert dict(zip(label_names(msg.layout.dim[0].label), values))['B2'] == CHANNELS.index('B2')


@pytest.mark.parametrize('names', [('F1', 'a,b'), ('F1', ''), ('F1', None)])
def test_names_that_cannot_be_told_apart_in_a_label_are_refused(names):
    with pytest.raises(ValueError, match='cannot label'):
        layout_label(names)


def test_a_channel_map_with_a_comma_in_a_name_is_refused():
    data = {'channels': ['L1', 'R,1', 'F1', 'B1'],
            'layouts': {'suit': {'left': ['L1'], 'right': ['R,1'], 'down': ['F1'], 'up': ['B1']}}}
    with pytest.raises(ChannelMapError, match="field \"channels\".*'R,1'.*label"):
        ChannelMap.from_dict(data)


def _serialized(n: int, layout_names=None, dims=None) -> tuple[bytes, list[float]]:
    values = [1.5 * i - 3.0 for i in range(n)]
    msg = Float64MultiArray(data=values)
    if layout_names is not None:
        msg.layout = named_layout(layout_names)
    if dims is not None:
        msg.layout.dim = dims
    return serialize_message(msg), values


@pytest.mark.parametrize('names', [None, CHANNELS, FIELDS, ('a',), ('ab',), ('abc',), ('abcd',)])
def test_the_bag_fast_path_reads_labelled_and_unlabelled_arrays(names):
    n = len(names) if names is not None else INPUT_SIZE
    data, values = _serialized(n, names)
    fast = float64_array(data)
    assert fast is not None and fast.tolist() == values
    assert list(deserialize_message(data, Float64MultiArray).data) == values   # what rclpy reads


def test_the_bag_fast_path_skips_any_number_of_dimensions_and_refuses_cut_messages():
    dims = [MultiArrayDimension(label='rows', size=2, stride=6), MultiArrayDimension(label='c', size=3, stride=3)]
    data, values = _serialized(6, dims=dims)
    assert float64_array(data).tolist() == values
    # A message cut anywhere is not read by the fast path (the full decoder then reports it).
    for end in range(len(data)):
        assert float64_array(data[:end]) is None, end
    # A dimension count larger than the message can hold (a damaged bag) is not followed.
    damaged = data[:4] + (10 ** 6).to_bytes(4, 'little') + data[8:]
    assert float64_array(damaged) is None
