"""The channel maps of config/hardware/channel_map.yaml: suit (Fig. 4) and arm (Table II)."""
import numpy as np
import pytest

from fabric_guidance.core.channels import ChannelMap, ChannelMapError
from fabric_guidance.paths import config_path

SUIT = ['F1', 'F2', 'F3', 'F4', 'B1', 'B2', 'B3', 'B4', 'L1', 'L2', 'R1', 'R2']
ARM = ['arm_i', 'arm_ii', 'arm_iii', 'arm_iv', 'arm_v', 'arm_vi']


@pytest.fixture(scope='module')
def cmap():
    return ChannelMap.load(config_path('hardware/channel_map.yaml'))


def test_channel_order_is_the_configured_one(cmap):
    assert list(cmap.channels) == SUIT + ARM


def test_suit_layout(cmap):
    out = dict(zip(cmap.channels, cmap.to_channels([1.0, 2.0, 3.0, 4.0], 'suit')))  # left, right, down, up
    assert [out[c] for c in ('L1', 'L2')] == [1.0, 1.0]            # left twist
    assert [out[c] for c in ('R1', 'R2')] == [2.0, 2.0]            # right twist
    assert [out[f'F{i}'] for i in range(1, 5)] == [3.0] * 4         # forward bend = down
    assert [out[f'B{i}'] for i in range(1, 5)] == [4.0] * 4         # backward bend = up
    assert all(out[c] == 0.0 for c in ARM)


def test_arm_layout_is_table_2(cmap):
    out = dict(zip(cmap.channels, cmap.to_channels([1.0, 2.0, 3.0, 4.0], 'arm')))
    assert (out['arm_i'], out['arm_iv']) == (4.0, 4.0)              # upward: (i) and (iv)
    assert (out['arm_iii'], out['arm_vi']) == (3.0, 3.0)            # downward: (iii) and (vi)
    assert out['arm_v'] == 1.0                                      # leftward: (v)
    assert out['arm_ii'] == 2.0                                     # rightward: (ii)
    assert all(out[c] == 0.0 for c in SUIT)


def test_back_to_directions(cmap):
    p = np.array([5.0, 0.0, 7.0, 0.0])
    for layout in ('suit', 'arm'):
        np.testing.assert_allclose(cmap.to_directions(cmap.to_channels(p, layout), layout), p)


def test_wrong_shapes_and_layouts(cmap):
    with pytest.raises(ValueError, match='4 direction pressures'):
        cmap.to_channels([1.0, 2.0], 'suit')
    with pytest.raises(ChannelMapError, match='unknown layout'):
        cmap.to_channels([0.0] * 4, 'legs')


GOOD = {'channels': ['a', 'b', 'c', 'd'],
        'layouts': {'x': {'left': ['a'], 'right': ['b'], 'down': ['c'], 'up': ['d']}}}


@pytest.mark.parametrize('patch, match', [
    ({'channels': []}, 'field "channels"'),
    ({'channels': ['a', 'a', 'c', 'd']}, 'more than once'),
    ({'layouts': {'x': {'left': ['a'], 'right': ['b'], 'down': ['c']}}}, 'layouts.x must name exactly'),
    ({'layouts': {'x': {'left': ['z'], 'right': ['b'], 'down': ['c'], 'up': ['d']}}}, "layouts.x.left: channel 'z'"),
    ({'layouts': {'x': {'left': ['a'], 'right': ['a'], 'down': ['c'], 'up': ['d']}}}, 'already drives'),
    ({'layouts': {'x': {'left': [], 'right': ['b'], 'down': ['c'], 'up': ['d']}}}, 'layouts.x.left must be'),
])
def test_bad_maps_name_the_field(patch, match):
    with pytest.raises(ChannelMapError, match=match):
        ChannelMap.from_dict({**GOOD, **patch})


def test_unreadable_file(tmp_path):
    bad = tmp_path / 'map.yaml'
    bad.write_text('channels: [a, b\n')
    with pytest.raises(ChannelMapError, match='cannot read channel map'):
        ChannelMap.load(bad)
