"""Direction pressures onto named PLC channels, in one fixed, configured order.

A channel map (config/hardware/channel_map.yaml) lists every channel in the order the command vector
uses (the ros2_controllers convention: a Float64MultiArray in a configured joint order) and,
per layout, which channels each of the four directions drives:

- layout "suit" (conditions 1 and 2): F1-F4 forward bend (down), B1-B4 backward bend (up),
  L1-L2 left twist, R1-R2 right twist (the paper's Fig. 4);
- layout "arm" (condition 3): the six arm muscles (i)-(vi), mapped as in the paper's Table II.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .safe_input import excerpt, load_yaml
from .geometry import DIRECTIONS


class ChannelMapError(ValueError):
    """A channel map file or mapping that is not usable, naming the field and the reason."""


#: Joins the names in the label of a per-channel array's layout (docs/interfaces.md, "Array
#: labels"), so no channel name may contain it.
LABEL_SEPARATOR = ','


def layout_label(names: Sequence[str]) -> str:
    """The label of the one layout dimension of a per-channel (or per-field) Float64MultiArray:
    the names in data order, joined by LABEL_SEPARATOR."""
    bad = [n for n in names if not isinstance(n, str) or not n or LABEL_SEPARATOR in n]
    if bad:
        raise ValueError(f'cannot label an array with {excerpt(bad)}: names must be non-empty strings '
                         f'without {LABEL_SEPARATOR!r}')
    return LABEL_SEPARATOR.join(names)


def label_names(label: str) -> tuple[str, ...]:
    """The names of a label layout_label() made, in data order."""
    return tuple(label.split(LABEL_SEPARATOR)) if label else ()


@dataclass(frozen=True)
class ChannelMap:
    channels: tuple[str, ...]
    #: layout name -> (n_channels x 4) 0/1 matrix: channel i is driven by direction k.
    _selection: Mapping[str, np.ndarray]

    @property
    def layouts(self) -> tuple[str, ...]:
        return tuple(self._selection)

    def channels_of(self, layout: str, direction: str) -> tuple[str, ...]:
        k = DIRECTIONS.index(direction)
        sel = self._selection_for(layout)
        return tuple(self.channels[i] for i in np.flatnonzero(sel[:, k]))

    def _selection_for(self, layout: str) -> np.ndarray:
        try:
            return self._selection[layout]
        except KeyError:
            raise ChannelMapError(f'unknown layout {excerpt(layout)}; the map has {list(self._selection)}') from None

    def to_channels(self, direction_pressures: Sequence[float], layout: str) -> np.ndarray:
        """Per-channel pressures (kPa) in the configured order; channels not used are 0."""
        p = np.asarray(direction_pressures, dtype=float)
        if p.shape != (len(DIRECTIONS),):
            raise ValueError(f'need {len(DIRECTIONS)} direction pressures {DIRECTIONS}, got shape {p.shape}')
        return self._selection_for(layout) @ p

    def to_directions(self, channel_pressures: Sequence[float], layout: str) -> np.ndarray:
        """Mean pressure per direction (left, right, down, up) from per-channel pressures."""
        c = np.asarray(channel_pressures, dtype=float)
        if c.shape != (len(self.channels),):
            raise ValueError(f'need {len(self.channels)} channel pressures, got shape {c.shape}')
        sel = self._selection_for(layout)
        return (c @ sel) / sel.sum(axis=0)

    @classmethod
    def from_dict(cls, data: Mapping, source: str = 'channel map') -> 'ChannelMap':
        if not isinstance(data, Mapping):
            raise ChannelMapError(f'{source}: expected a mapping with "channels" and "layouts"')
        channels = data.get('channels')
        if not isinstance(channels, list) or not channels or not all(isinstance(c, str) and c for c in channels):
            raise ChannelMapError(f'{source}: field "channels" must be a non-empty list of channel names')
        if len(set(channels)) != len(channels):
            dup = sorted({c for c in channels if channels.count(c) > 1})
            raise ChannelMapError(f'{source}: field "channels" names {dup} more than once')
        joined = [c for c in channels if LABEL_SEPARATOR in c]
        if joined:
            raise ChannelMapError(f'{source}: field "channels": {excerpt(joined)} contain {LABEL_SEPARATOR!r}, '
                                  'which separates the names in the pressure arrays\' layout label')
        layouts = data.get('layouts')
        if not isinstance(layouts, Mapping) or not layouts:
            raise ChannelMapError(f'{source}: field "layouts" must map layout names to directions')
        selection = {}
        for name, directions in layouts.items():
            where = f'{source}: layouts.{name}'
            if not isinstance(directions, Mapping) or set(directions) != set(DIRECTIONS):
                got = sorted(directions) if isinstance(directions, Mapping) else directions
                raise ChannelMapError(f'{where} must name exactly the directions {list(DIRECTIONS)}, '
                                      f'got {excerpt(got)}')
            sel = np.zeros((len(channels), len(DIRECTIONS)))
            for k, direction in enumerate(DIRECTIONS):
                names = directions[direction]
                if not isinstance(names, list) or not names:
                    raise ChannelMapError(f'{where}.{direction} must be a non-empty list of channels')
                for ch in names:
                    if ch not in channels:
                        raise ChannelMapError(f'{where}.{direction}: channel {excerpt(ch)} is not in "channels"')
                    i = channels.index(ch)
                    if sel[i].any():
                        raise ChannelMapError(f'{where}.{direction}: channel {excerpt(ch)} '
                                              'already drives another direction')
                    sel[i, k] = 1.0
            sel.setflags(write=False)
            selection[str(name)] = sel
        return cls(tuple(channels), selection)

    @classmethod
    def load(cls, path: str | Path) -> 'ChannelMap':
        return cls.from_dict(load_yaml(path, 'channel map', ChannelMapError), source=str(path))
