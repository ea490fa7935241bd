"""Which PLC register carries which channel, and how kPa become 16-bit register counts.

The register map (config/hardware/plc_register_map.yaml) is the single place that says where each
channel's pressure command goes (a holding register), where its measured pressure comes from
(an input register), where the heartbeat goes, and how pressures are scaled. It is validated
when loaded, so a bad file fails at start-up with the file, the field and the reason, not
later on the wire.

Encoding is where the pressure limit is enforced last before the wire: every command is
clamped to [0, p_max_kpa] before scaling and anything non-finite becomes 0 (vent), so no
count above ``p_max_counts`` can be produced whatever the caller passes.

Addresses are 0-based protocol addresses (what goes into the Modbus frame), not the
1-based "40001"-style register numbers of some PLC manuals.

Several PLCs: a file with ``endpoints`` names each PLC (host, port, unit id) and the channels
it serves, each with its own register layout (by default the PLC contract's: commands 0..n-1,
sequence n, heartbeat n+1). :class:`PlcLayout` reads either form; a file without
``endpoints`` is one endpoint whose address the node's parameters give (the original form).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.safe_input import InputFileError, excerpt, load_yaml

#: Largest value of a 16-bit register and largest protocol address.
REGISTER_MAX = 0xFFFF
#: A Modbus "write multiple registers" request carries at most 123 registers; keeping every
#: channel in one request keeps a command vector atomic on the PLC side.
MAX_CHANNELS = 123
#: Modbus unit ids a server answers to (0 is broadcast: no reply, so no confirmation).
UNIT_ID_RANGE = (1, 247)

_TOP_FIELDS = ('unit_id', 'p_max_kpa', 'counts_per_kpa', 'heartbeat_register', 'channels')
#: Fields a map may leave out (a PLC program without write sequencing, or without the vent latch).
_OPTIONAL_FIELDS = ('sequence_register', 'vent_register', 'claim_holder_register')
#: Values of the vent register (docs/plc.md): written, VENT_REQUEST latches the vent (from any
#: connection) and REARM releases it (the write claim's holder only); read, 1 while latched.
VENT_REQUEST, REARM = 1, 2
#: Input registers from claim_holder_register on: the write claim holder's IPv4 address (high
#: and low 16 bits) and TCP port; all 0 while the claim is free.
CLAIM_HOLDER_REGISTERS = 3
_CHANNEL_FIELDS = ('name', 'command_register', 'measured_register')
#: The fields of a file with several PLCs, and of each of its endpoints.
_LAYOUT_FIELDS = ('p_max_kpa', 'counts_per_kpa', 'endpoints')
_ENDPOINT_FIELDS = ('name', 'host', 'port', 'unit_id', 'heartbeat_register', 'sequence_register',
                    'vent_register', 'claim_holder_register', 'channels')
_ENDPOINT_REQUIRED = ('name', 'host', 'unit_id', 'channels')


class RegisterMapError(ValueError):
    """A register map that is not usable; the message names the file, the field and the reason."""


def _read(path: Path) -> Any:
    """A register map file, parsed by the package's safe YAML loader (one-line errors)."""
    try:
        return load_yaml(path, 'register map')
    except InputFileError as exc:
        raise RegisterMapError(str(exc)) from None


@dataclass(frozen=True)
class ChannelRegisters:
    """One channel: its name, command holding register and measured input register."""
    name: str
    command_register: int
    measured_register: int


@dataclass(frozen=True)
class RegisterMap:
    """Validated register map; build it with :meth:`load` or :meth:`from_dict`."""
    unit_id: int
    p_max_kpa: float
    counts_per_kpa: float
    heartbeat_register: int
    channels: tuple[ChannelRegisters, ...]
    source: str = 'register map'
    #: Holding register right after the command block that carries each write's sequence
    #: number (plc/sequence.py); None: the PLC does not check write order.
    sequence_register: int | None = None
    #: Holding register of the PLC's vent latch (VENT_REQUEST from any client, REARM from the
    #: claim's holder); None: the PLC has none.
    vent_register: int | None = None
    #: First of the CLAIM_HOLDER_REGISTERS input registers naming the claim's holder; None: none.
    claim_holder_register: int | None = None

    # ------------------------------------------------------------------ views
    @property
    def names(self) -> tuple[str, ...]:
        """Channel names in command-vector order."""
        return tuple(c.name for c in self.channels)

    @property
    def command_registers(self) -> tuple[int, ...]:
        """Holding-register addresses of the commands, in channel order."""
        return tuple(c.command_register for c in self.channels)

    @property
    def measured_registers(self) -> tuple[int, ...]:
        """Input-register addresses of the measured pressures, in channel order."""
        return tuple(c.measured_register for c in self.channels)

    @property
    def p_max_counts(self) -> int:
        """Largest command count ever produced: p_max_kpa * counts_per_kpa, rounded down.

        Rounded down (not to nearest) so that decode(p_max_counts) never exceeds p_max_kpa;
        the product and the quotient round too (p_max 999.9999999999999 at 0.2 counts/kPa gives
        floor 200, and 200 / 0.2 = 1000.0 > p_max by one ulp), so step down while it does.
        """
        n = int(math.floor(self.p_max_kpa * self.counts_per_kpa))
        while n > 0 and n / self.counts_per_kpa > self.p_max_kpa:
            n -= 1
        return n

    def __len__(self) -> int:
        return len(self.channels)

    def command_block(self) -> tuple[int, int] | None:
        """(start_address, count) if the command registers are contiguous and ascending.

        Then one write-multiple-registers request writes the whole command vector, so the
        PLC never sees half of an update. None otherwise (the client then writes one by one).
        """
        return _block(self.command_registers)

    def measured_block(self) -> tuple[int, int] | None:
        """(start_address, count) if the measured input registers are contiguous, else None."""
        return _block(self.measured_registers)

    def sequenced_block(self) -> tuple[int, int] | None:
        """(start_address, count) of the command block plus the sequence register after it, when
        the map has one: what a sequenced command write covers. None otherwise."""
        block = self.command_block()
        if block is None or self.sequence_register is None or self.sequence_register != block[0] + block[1]:
            return None
        return block[0], block[1] + 1

    def is_mapped_holding(self, address: int) -> bool:
        """True for the holding registers the package may write: the commands, the heartbeat and
        the sequence register."""
        return (address == self.heartbeat_register or address == self.sequence_register
                or (self.vent_register is not None and address == self.vent_register)
                or address in self.command_registers)

    # ------------------------------------------------------------- conversion
    def encode(self, pressures_kpa: Sequence[float]) -> list[int]:
        """Command pressures (kPa, channel order) -> register counts, safe by construction.

        Each value is clamped to [0, p_max_kpa] before scaling; NaN and +-inf become 0 (vent:
        a value that is not a number is not a command to pressurise). A vector of the wrong
        length raises ValueError rather than being padded or truncated.
        """
        p = np.asarray(pressures_kpa, dtype=float)
        if p.shape != (len(self.channels),):
            raise ValueError(f'{self.source}: need {len(self.channels)} pressures (kPa) in the order '
                             f'{list(self.names)}, got shape {p.shape}')
        p = np.where(np.isfinite(p), p, 0.0)
        p = np.clip(p, 0.0, self.p_max_kpa)
        counts = np.rint(p * self.counts_per_kpa)
        # Rounding to nearest could step one count past a p_max that is not a whole count.
        counts = np.clip(counts, 0, self.p_max_counts)
        return counts.astype(np.int64).tolist()

    def decode(self, counts: Sequence[int]) -> np.ndarray:
        """Register counts (channel order) -> pressures in kPa."""
        c = np.asarray(counts, dtype=float)
        if c.shape != (len(self.channels),):
            raise ValueError(f'{self.source}: need {len(self.channels)} register values, got shape {c.shape}')
        return c / self.counts_per_kpa

    # ---------------------------------------------------------------- loading
    @classmethod
    def load(cls, path: str | Path, expected_channels: Sequence[str] | None = None) -> 'RegisterMap':
        """Read and validate a register map YAML file."""
        path = Path(path)
        return cls.from_dict(_read(path), source=str(path), expected_channels=expected_channels)

    @classmethod
    def from_dict(cls, data: Any, source: str = 'register map',
                  expected_channels: Sequence[str] | None = None) -> 'RegisterMap':
        """Validate a parsed mapping; ``expected_channels`` (e.g. the channel map's order) must
        then match the channel names exactly, in order."""
        def fail(field: str, reason: str) -> RegisterMapError:
            return RegisterMapError(f'{source}: field "{field}" {reason}')

        if isinstance(data, Mapping) and 'endpoints' in data:
            layout = PlcLayout.from_dict(data, source, expected_channels)
            if len(layout.endpoints) != 1:
                names = [e.name for e in layout.endpoints]
                raise fail('endpoints', f'names {len(names)} PLCs {names}: this reader takes one; '
                                        'name the endpoint (PlcLayout.endpoint, mock_plc '
                                        'parameter "endpoint")')
            return layout.endpoints[0].map
        if not isinstance(data, Mapping):
            raise RegisterMapError(f'{source}: expected a mapping with the fields {list(_TOP_FIELDS)}, '
                                   f'got {type(data).__name__}')
        for field in _TOP_FIELDS:
            if field not in data:
                raise fail(field, 'is missing')
        # Unknown fields are rejected: a misspelt field in a safety configuration should not
        # be silently ignored.
        for field in data:
            if field not in _TOP_FIELDS + _OPTIONAL_FIELDS:
                raise fail(field, f'is not a known field (known: {list(_TOP_FIELDS + _OPTIONAL_FIELDS)})')

        unit_id = _integer(data['unit_id'], *UNIT_ID_RANGE, fail, 'unit_id')
        heartbeat = _integer(data['heartbeat_register'], 0, REGISTER_MAX, fail, 'heartbeat_register')
        p_max = _positive(data['p_max_kpa'], fail, 'p_max_kpa')
        scale = _positive(data['counts_per_kpa'], fail, 'counts_per_kpa')
        if p_max * scale > REGISTER_MAX:
            raise fail('p_max_kpa', f'* counts_per_kpa = {p_max * scale:g} counts does not fit a 16-bit '
                                    f'register (max {REGISTER_MAX})')

        raw = data['channels']
        if not isinstance(raw, list) or not raw:
            raise fail('channels', 'must be a non-empty list of {name, command_register, measured_register}')
        if len(raw) > MAX_CHANNELS:
            raise fail('channels', f'has {len(raw)} entries; one Modbus write carries at most {MAX_CHANNELS}')
        channels = []
        for i, entry in enumerate(raw):
            where = f'channels[{i}]'
            if not isinstance(entry, Mapping):
                raise fail(where, f'must be a mapping with {list(_CHANNEL_FIELDS)}, got {excerpt(entry)}')
            for field in _CHANNEL_FIELDS:
                if field not in entry:
                    raise fail(f'{where}.{field}', 'is missing')
            for field in entry:
                if field not in _CHANNEL_FIELDS:
                    raise fail(f'{where}.{field}', f'is not a known field (known: {list(_CHANNEL_FIELDS)})')
            name = entry['name']
            if not isinstance(name, str) or not name:
                raise fail(f'{where}.name', f'must be a non-empty string, got {excerpt(name)}')
            channels.append(ChannelRegisters(
                name,
                _integer(entry['command_register'], 0, REGISTER_MAX, fail, f'{where}.command_register'),
                _integer(entry['measured_register'], 0, REGISTER_MAX, fail, f'{where}.measured_register')))

        for field in _CHANNEL_FIELDS:
            _unique([getattr(c, field) for c in channels], fail, field)
        for i, c in enumerate(channels):
            if c.command_register == heartbeat:
                raise fail('heartbeat_register', f'{heartbeat} is also the command register of channel '
                                                 f'{excerpt(c.name)} (channels[{i}])')
        sequence = None
        if data.get('sequence_register') is not None:
            sequence = _integer(data['sequence_register'], 0, REGISTER_MAX, fail, 'sequence_register')
            block = _block([c.command_register for c in channels])
            if block is None or sequence != block[0] + block[1]:
                # One write must carry the commands and their number, or the PLC could apply
                # commands under another write's number.
                raise fail('sequence_register', f'{sequence} must be the register right after a contiguous, '
                                                'ascending block of command registers'
                                                + (f' ({block[0] + block[1]})' if block else ''))
            if sequence == heartbeat:
                raise fail('sequence_register', f'{sequence} is also the heartbeat_register')
        vent = None
        if data.get('vent_register') is not None:
            vent = _integer(data['vent_register'], 0, REGISTER_MAX, fail, 'vent_register')
            taken = {heartbeat: 'heartbeat_register', sequence: 'sequence_register'}
            taken.update({c.command_register: f'the command register of channel {excerpt(c.name)}'
                          for c in channels})
            if vent in taken:
                raise fail('vent_register', f'{vent} is also {taken[vent]}')
        holder = None
        if data.get('claim_holder_register') is not None:
            holder = _integer(data['claim_holder_register'], 0, REGISTER_MAX - CLAIM_HOLDER_REGISTERS + 1,
                              fail, 'claim_holder_register')
            clash = [c.name for c in channels
                     if holder <= c.measured_register < holder + CLAIM_HOLDER_REGISTERS]
            if clash:
                raise fail('claim_holder_register', f'{holder}..{holder + CLAIM_HOLDER_REGISTERS - 1} '
                                                    f'overlaps the measured registers of {clash}')
        if expected_channels is not None:
            names = [c.name for c in channels]
            if names != list(expected_channels):
                raise fail('channels', f'names {names} do not match the expected channels, in order, '
                                       f'{list(expected_channels)}')
        return cls(unit_id, p_max, scale, heartbeat, tuple(channels), source, sequence_register=sequence,
                   vent_register=vent, claim_holder_register=holder)


@dataclass(frozen=True)
class PlcEndpoint:
    """One PLC: where it is, and its register map (the channels it serves, its own layout).

    ``host``/``port`` are None for the single-PLC form of the file: the node's parameters say.
    ``indices``: where its channels sit in the command vector (the channel map's order).
    """
    name: str
    host: str | None
    port: int | None
    map: RegisterMap
    indices: tuple[int, ...]


@dataclass(frozen=True)
class PlcLayout:
    """Every PLC of a register map file, and which channels each serves."""
    endpoints: tuple[PlcEndpoint, ...]
    names: tuple[str, ...]   #: channel order of the whole command vector
    p_max_kpa: float
    source: str = 'register map'

    def __len__(self) -> int:
        return len(self.names)

    def endpoint(self, name: str = '') -> PlcEndpoint:
        """The endpoint called ``name``; '' = the only one (an error when there are several)."""
        if not name:
            if len(self.endpoints) == 1:
                return self.endpoints[0]
            raise RegisterMapError(f'{self.source}: names {len(self.endpoints)} PLCs '
                                   f'{[e.name for e in self.endpoints]}: say which one')
        for e in self.endpoints:
            if e.name == name:
                return e
        raise RegisterMapError(f'{self.source}: no endpoint named {name!r} '
                               f'(known: {[e.name for e in self.endpoints]})')

    @classmethod
    def load(cls, path: str | Path, expected_channels: Sequence[str] | None = None) -> 'PlcLayout':
        path = Path(path)
        return cls.from_dict(_read(path), str(path), expected_channels)

    @classmethod
    def from_dict(cls, data: Any, source: str = 'register map',
                  expected_channels: Sequence[str] | None = None) -> 'PlcLayout':
        """Either form: with ``endpoints`` (several PLCs) or the single-PLC fields."""
        def fail(field: str, reason: str) -> RegisterMapError:
            return RegisterMapError(f'{source}: field "{field}" {reason}')

        if not (isinstance(data, Mapping) and 'endpoints' in data):
            m = RegisterMap.from_dict(data, source, expected_channels)
            only = PlcEndpoint('plc', None, None, m, tuple(range(len(m))))
            return cls((only,), m.names, m.p_max_kpa, source)
        for field in data:
            if field not in _LAYOUT_FIELDS:
                raise fail(field, f'is not a known field next to "endpoints" (known: '
                                  f'{list(_LAYOUT_FIELDS)}; unit_id, registers and channels go '
                                  'into each endpoint)')
        for field in ('p_max_kpa', 'counts_per_kpa'):
            if field not in data:
                raise fail(field, 'is missing')
        raw = data['endpoints']
        if not isinstance(raw, list) or not raw:
            raise fail('endpoints', 'must be a non-empty list of '
                                    '{name, host, port, unit_id, channels}')
        maps, seen_names, seen_addresses = [], {}, {}
        for i, entry in enumerate(raw):
            where = f'endpoints[{i}]'
            if not isinstance(entry, Mapping):
                raise fail(where, f'must be a mapping with {list(_ENDPOINT_FIELDS)}, '
                                  f'got {excerpt(entry)}')
            for field in entry:
                if field not in _ENDPOINT_FIELDS:
                    raise fail(f'{where}.{field}',
                               f'is not a known field (known: {list(_ENDPOINT_FIELDS)})')
            for field in _ENDPOINT_REQUIRED:
                if field not in entry:
                    raise fail(f'{where}.{field}', 'is missing')
            name, host = entry['name'], entry['host']
            if not isinstance(name, str) or not name:
                raise fail(f'{where}.name', f'must be a non-empty string, got {excerpt(name)}')
            if name in seen_names:
                raise fail(f'{where}.name',
                           f'{name!r} duplicates endpoints[{seen_names[name]}].name')
            seen_names[name] = i
            if not isinstance(host, str) or not host:
                raise fail(f'{where}.host',
                           f'must be a non-empty string (address of the PLC), got {excerpt(host)}')
            port = _integer(entry.get('port', 502), 1, 65535, fail, f'{where}.port')
            unit_id = _integer(entry['unit_id'], *UNIT_ID_RANGE, fail, f'{where}.unit_id')
            if (host, port, unit_id) in seen_addresses:
                raise fail(f'{where}', f'{host}:{port} unit id {unit_id} is also '
                                       f'endpoints[{seen_addresses[(host, port, unit_id)]}]')
            seen_addresses[(host, port, unit_id)] = i
            channels = entry['channels']
            n = len(channels) if isinstance(channels, list) else 0
            sub = {'unit_id': unit_id, 'p_max_kpa': data['p_max_kpa'],
                   'counts_per_kpa': data['counts_per_kpa'], 'channels': channels,
                   # The PLC contract's layout unless stated: sequence n, heartbeat n + 1,
                   # vent n + 2; the claim holder's address in input registers n..n + 2.
                   'heartbeat_register': entry.get('heartbeat_register', n + 1),
                   'sequence_register': entry.get('sequence_register', n),
                   'vent_register': entry.get('vent_register', n + 2),
                   'claim_holder_register': entry.get('claim_holder_register', n)}
            m = RegisterMap.from_dict(sub, f'{source}: {where} ({name})')
            maps.append((name, host, port, m))
        all_names = [c for *_, m in maps for c in m.names]
        owner: dict[str, str] = {}
        for name, *_, m in maps:
            for c in m.names:
                if c in owner:
                    raise fail('endpoints',
                               f'channel {c!r} is served by both {owner[c]!r} and {name!r}')
                owner[c] = name
        order = tuple(all_names) if expected_channels is None else tuple(expected_channels)
        if sorted(order) != sorted(all_names):
            missing = sorted(set(order) - set(all_names))
            extra = sorted(set(all_names) - set(order))
            raise fail('endpoints', f'channels do not match the expected channels {list(order)}: '
                                    f'missing {missing}, unknown {extra}')
        index = {c: i for i, c in enumerate(order)}
        endpoints = tuple(PlcEndpoint(name, host, port, m, tuple(index[c] for c in m.names))
                          for name, host, port, m in maps)
        return cls(endpoints, order, maps[0][3].p_max_kpa, source)


# ------------------------------------------------------------------- helpers
def _block(addresses: Sequence[int]) -> tuple[int, int] | None:
    start = addresses[0]
    if list(addresses) == list(range(start, start + len(addresses))):
        return start, len(addresses)
    return None


def _integer(value: Any, lo: int, hi: int, fail, field: str) -> int:
    # bool is an int subclass; "true" as an address is a typo, not 1.
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise fail(field, f'must be an integer in {lo}..{hi}, got {excerpt(value)}')
    return value


def _positive(value: Any, fail, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise fail(field, f'must be a positive finite number, got {excerpt(value)}')
    return float(value)


def _unique(values: list, fail, field: str) -> None:
    seen: dict = {}
    for i, v in enumerate(values):
        if v in seen:
            raise fail(f'channels[{i}].{field}', f'duplicates {excerpt(v)} of channels[{seen[v]}].{field}')
        seen[v] = i
