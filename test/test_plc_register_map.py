"""Register map: validation names file, field and reason; encoding can never exceed p_max."""
import copy
import dataclasses
import math

import numpy as np
import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fabric_guidance.paths import config_path
from fabric_guidance.plc.register_map import PlcLayout, RegisterMap, RegisterMapError

CHANNELS = ['F1', 'F2', 'F3', 'F4', 'B1', 'B2', 'B3', 'B4', 'L1', 'L2', 'R1', 'R2',
            'arm_i', 'arm_ii', 'arm_iii', 'arm_iv', 'arm_v', 'arm_vi']


def valid_dict():
    return {
        'unit_id': 1, 'p_max_kpa': 375.0, 'counts_per_kpa': 10, 'heartbeat_register': 100,
        'channels': [{'name': n, 'command_register': i, 'measured_register': i} for i, n in enumerate(CHANNELS)],
    }


@pytest.fixture(scope='module')
def reg_map():
    return RegisterMap.from_dict(valid_dict(), source='test.yaml')


def test_shipped_map_matches_channel_map_order():
    # Read the channel map's order straight from its file: this test is about the PLC layer only.
    channels = tuple(yaml.safe_load(config_path('hardware/channel_map.yaml').read_text())['channels'])
    m = RegisterMap.load(config_path('hardware/plc_register_map.yaml'), expected_channels=channels)
    assert m.names == tuple(CHANNELS) == channels
    assert m.p_max_kpa == 375.0 and m.p_max_counts == 3750
    assert m.command_block() == (0, len(CHANNELS))
    assert not set(m.command_registers) & {m.heartbeat_register}
    assert m.source.endswith('hardware/plc_register_map.yaml')


def _mutate(path, value):
    """valid_dict() with the item at `path` (keys/indices) set to value, or deleted if value is ...."""
    d = valid_dict()
    target = d
    for key in path[:-1]:
        target = target[key]
    if value is ...:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return d


@pytest.mark.parametrize('path, value, field, reason', [
    (('unit_id',), ..., 'unit_id', 'missing'),
    (('channels',), ..., 'channels', 'missing'),
    (('unit_id',), 'one', 'unit_id', 'integer'),
    (('unit_id',), 0, 'unit_id', '1..247'),
    (('heartbeat_register',), 1.5, 'heartbeat_register', 'integer'),
    (('heartbeat_register',), True, 'heartbeat_register', 'integer'),
    (('heartbeat_register',), 65536, 'heartbeat_register', '0..65535'),
    (('heartbeat_register',), 3, 'heartbeat_register', 'command register of channel'),
    (('p_max_kpa',), 'high', 'p_max_kpa', 'positive finite'),
    (('p_max_kpa',), float('nan'), 'p_max_kpa', 'positive finite'),
    (('counts_per_kpa',), 0, 'counts_per_kpa', 'positive finite'),
    (('counts_per_kpa',), -10, 'counts_per_kpa', 'positive finite'),
    (('counts_per_kpa',), 200, 'p_max_kpa', '16-bit'),
    (('p_max_kpa',), 6554.0, 'p_max_kpa', '16-bit'),
    (('channels',), [], 'channels', 'non-empty list'),
    (('channels',), 'F1', 'channels', 'non-empty list'),
    (('channels', 2), 'F3', 'channels[2]', 'mapping'),
    (('channels', 2, 'name'), ..., 'channels[2].name', 'missing'),
    (('channels', 2, 'name'), '', 'channels[2].name', 'non-empty string'),
    (('channels', 2, 'name'), 'F1', 'channels[2].name', 'duplicates'),
    (('channels', 5, 'command_register'), 0, 'channels[5].command_register', 'duplicates'),
    (('channels', 5, 'measured_register'), 4, 'channels[5].measured_register', 'duplicates'),
    (('channels', 5, 'command_register'), -1, 'channels[5].command_register', '0..65535'),
    (('channels', 5, 'measured_register'), 70000, 'channels[5].measured_register', '0..65535'),
    (('channels', 5, 'command_register'), '5', 'channels[5].command_register', 'integer'),
    (('channels', 5, 'gain'), 2, 'channels[5].gain', 'not a known field'),
    (('p_max_kp',), 300, 'p_max_kp', 'not a known field'),
])
def test_validation_names_source_field_and_reason(path, value, field, reason):
    with pytest.raises(RegisterMapError) as err:
        RegisterMap.from_dict(_mutate(path, value), source='my_map.yaml')
    msg = str(err.value)
    assert msg.startswith('my_map.yaml: ')
    assert f'"{field}"' in msg
    assert reason in msg


def test_not_a_mapping():
    with pytest.raises(RegisterMapError, match='my_map.yaml: expected a mapping'):
        RegisterMap.from_dict([1, 2], source='my_map.yaml')


def test_expected_channels_must_match_in_order():
    swapped = CHANNELS[:]
    swapped[0], swapped[1] = swapped[1], swapped[0]
    with pytest.raises(RegisterMapError, match=r'x.yaml: field "channels" .*expected channels'):
        RegisterMap.from_dict(valid_dict(), source='x.yaml', expected_channels=swapped)
    with pytest.raises(RegisterMapError, match='"channels"'):
        RegisterMap.from_dict(valid_dict(), source='x.yaml', expected_channels=CHANNELS[:-1])
    assert RegisterMap.from_dict(valid_dict(), expected_channels=CHANNELS).names == tuple(CHANNELS)


def test_load_names_the_file(tmp_path):
    missing = tmp_path / 'nope.yaml'
    with pytest.raises(RegisterMapError, match='nope.yaml'):
        RegisterMap.load(missing)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('unit_id: [1\n')
    with pytest.raises(RegisterMapError, match='bad.yaml'):
        RegisterMap.load(bad)
    wrong = tmp_path / 'wrong.yaml'
    wrong.write_text('unit_id: 1\n')
    with pytest.raises(RegisterMapError, match=r'wrong.yaml: field "p_max_kpa" is missing'):
        RegisterMap.load(wrong)


def test_map_is_frozen(reg_map):
    with pytest.raises(dataclasses.FrozenInstanceError):
        reg_map.p_max_kpa = 1000.0


def test_encode_clamps_to_p_max_and_vents_non_finite(reg_map):
    n = len(reg_map)
    p = np.full(n, 100.0)
    p[:6] = [1000.0, float('nan'), float('inf'), float('-inf'), -50.0, 375.0]
    counts = reg_map.encode(p)
    assert counts[:6] == [reg_map.p_max_counts, 0, 0, 0, 0, 3750]
    assert counts[6:] == [1000] * (n - 6)
    assert all(type(c) is int for c in counts)
    assert reg_map.encode([1e300] * n) == [3750] * n
    assert reg_map.encode([-0.0] * n) == [0] * n


def test_encode_rejects_wrong_shape(reg_map):
    n = len(reg_map)
    for bad in ([0.0] * (n - 1), [0.0] * (n + 1), [], np.zeros((n, 1))):
        with pytest.raises(ValueError, match='need 18 pressures'):
            reg_map.encode(bad)


def test_decode_and_wrong_length(reg_map):
    assert np.allclose(reg_map.decode([3750] + [1] * 17), [375.0] + [0.1] * 17)
    with pytest.raises(ValueError):
        reg_map.decode([0] * 3)


@given(st.lists(st.floats(min_value=0.0, max_value=375.0), min_size=18, max_size=18))
def test_decode_encode_round_trip(pressures):
    m = RegisterMap.from_dict(valid_dict())
    back = m.decode(m.encode(pressures))
    assert np.all(np.abs(back - pressures) <= 1.0 / m.counts_per_kpa)


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=18, max_size=18))
def test_encode_never_leaves_0_to_p_max_counts(pressures):
    m = RegisterMap.from_dict(valid_dict())
    counts = m.encode(pressures)
    assert all(0 <= c <= m.p_max_counts for c in counts)
    assert np.all(m.decode(counts) <= m.p_max_kpa)


@settings(max_examples=200)
@given(p_max=st.floats(0.01, 1000.0), scale=st.floats(0.01, 60.0),
       pressure=st.floats(allow_nan=True, allow_infinity=True))
# floor(p_max * scale) = 200 but 200 / 0.2 = 1000.0 > p_max by one ulp (found by chance once).
@example(p_max=999.9999999999999, scale=0.2, pressure=999.9999999999999)
def test_encode_bound_holds_for_any_valid_scaling(p_max, scale, pressure):
    # Scalings where p_max * counts_per_kpa is not a whole number exercise the rounding clamp.
    d = valid_dict()
    d['p_max_kpa'], d['counts_per_kpa'] = p_max, scale
    m = RegisterMap.from_dict(d)
    counts = m.encode([pressure] * len(m))
    assert all(0 <= c <= m.p_max_counts <= 65535 for c in counts)
    assert m.p_max_counts / m.counts_per_kpa <= m.p_max_kpa
    if math.isfinite(pressure) and 0 <= pressure <= p_max:
        assert abs(m.decode(counts)[0] - pressure) <= 1.0 / scale


def test_command_block_and_mapped_holding():
    m = RegisterMap.from_dict(valid_dict())
    assert m.command_block() == (0, 18) and m.measured_block() == (0, 18)
    assert m.is_mapped_holding(0) and m.is_mapped_holding(17) and m.is_mapped_holding(100)
    assert not m.is_mapped_holding(18) and not m.is_mapped_holding(99)

    gappy = copy.deepcopy(valid_dict())
    gappy['channels'][5]['command_register'] = 40     # a gap
    assert RegisterMap.from_dict(gappy).command_block() is None
    descending = valid_dict()
    for i, ch in enumerate(descending['channels']):
        ch['command_register'] = 17 - i
    assert RegisterMap.from_dict(descending).command_block() is None
    shifted = valid_dict()
    for ch in shifted['channels']:
        ch['command_register'] += 200
    assert RegisterMap.from_dict(shifted).command_block() == (200, 18)


def test_sequence_register_is_optional_and_must_follow_the_command_block():
    assert RegisterMap.from_dict(valid_dict()).sequence_register is None
    assert RegisterMap.from_dict(valid_dict()).sequenced_block() is None
    m = RegisterMap.from_dict(dict(valid_dict(), sequence_register=18))
    assert m.sequenced_block() == (0, 19) and m.is_mapped_holding(18) and not m.is_mapped_holding(19)
    shipped = RegisterMap.load(config_path('hardware/plc_register_map.yaml'))
    assert shipped.sequence_register == 18 and shipped.sequenced_block() == (0, 19)
    for value, reason in [(19, 'right after'), (5, 'right after'), ('18', 'integer'), (70000, '0..65535')]:
        with pytest.raises(RegisterMapError) as err:
            RegisterMap.from_dict(dict(valid_dict(), sequence_register=value), source='m.yaml')
        assert '"sequence_register"' in str(err.value) and reason in str(err.value), str(err.value)
    gappy = valid_dict()
    gappy['channels'][5]['command_register'] = 40
    with pytest.raises(RegisterMapError, match='"sequence_register".*contiguous'):
        RegisterMap.from_dict(dict(gappy, sequence_register=18))
    on_heartbeat = dict(valid_dict(), sequence_register=18, heartbeat_register=18)
    with pytest.raises(RegisterMapError, match='"sequence_register".*heartbeat'):
        RegisterMap.from_dict(on_heartbeat)


def test_the_vent_and_claim_holder_registers_are_optional_and_must_not_overlap():
    assert RegisterMap.from_dict(valid_dict()).vent_register is None
    shipped = RegisterMap.load(config_path('hardware/plc_register_map.yaml'))
    assert (shipped.vent_register, shipped.claim_holder_register) == (20, 18)
    assert shipped.is_mapped_holding(20) and not shipped.is_mapped_holding(21)
    for field, value, reason in [('vent_register', 100, 'heartbeat_register'),
                                 ('vent_register', 3, 'command register of channel'),
                                 ('vent_register', 18.0, 'integer'),
                                 ('claim_holder_register', 16, 'overlaps the measured registers'),
                                 ('claim_holder_register', 65534, '0..65533')]:
        with pytest.raises(RegisterMapError) as err:
            RegisterMap.from_dict(dict(valid_dict(), **{field: value}), source='m.yaml')
        assert f'"{field}"' in str(err.value) and reason in str(err.value), str(err.value)
    # Several PLCs: each endpoint has the contract's layout, the vent register n + 2 included.
    layout = PlcLayout.from_dict({'p_max_kpa': 375.0, 'counts_per_kpa': 10, 'endpoints': [
        {'name': 'front', 'host': '10.0.0.1', 'unit_id': 1,
         'channels': [{'name': n, 'command_register': i, 'measured_register': i}
                      for i, n in enumerate(CHANNELS[:8])]}]})
    front = layout.endpoint('front').map
    assert (front.sequence_register, front.heartbeat_register, front.vent_register,
            front.claim_holder_register) == (8, 9, 10, 8)
