"""The mock PLC's write records as a file, and the invariants every test graph is held to.

The mock PLC (modbus.MockPlcServer) records what clients wrote to its holding registers. With
a records file it also keeps them as JSON on disk, so that they can be checked after its
process has ended (process_graph.Graph does, for every mock_plc it started):

- ``over_limit_count`` / ``over_limit_writes``: writes above p_max counts to a command register;
- ``out_of_map_count`` / ``out_of_map_writes``: writes to a holding register outside the map;
- ``stale_count`` / ``stale_writes``: command writes refused as older than the last applied
  (sequence.py): a fault that was handled, not a violation;
- ``max_written_counts``: per channel, the largest count ever written;
- ``writes``, ``watchdog_trips``, ``p_max_kpa``, ``p_max_counts``, ``counts_per_kpa``.

A register holds a 16-bit integer, so no non-finite value can reach one over Modbus; a NaN
or inf command is turned into 0 before encoding (register_map.RegisterMap.encode). What can
go wrong on the wire is a count above p_max or an address outside the map, and those are what
``violations`` reports. Plain Python: no pymodbus, no ROS.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from ..atomic import write_text

#: Entries kept per list in the file (the counts are always complete).
MAX_LISTED = 100


def write_records(path: str | Path, records: dict) -> None:
    """Write atomically: a reader sees the previous file or this one, never half of one."""
    write_text(path, json.dumps(records))


def load_records(path: str | Path) -> dict:
    return json.loads(Path(path).read_text())


def violations(records: dict, source: str = 'mock PLC') -> list[str]:
    """Every broken invariant in `records`, one line each; [] when there is none."""
    found = []
    p_max_counts = records['p_max_counts']
    if records['over_limit_count']:
        found.append(f'{source}: {records["over_limit_count"]} writes above p_max ({records["p_max_kpa"]} kPa = '
                     f'{p_max_counts} counts) to command registers, (address, counts): '
                     f'{records["over_limit_writes"]}')
    if records['out_of_map_count']:
        found.append(f'{source}: {records["out_of_map_count"]} writes to holding registers outside the register '
                     f'map, (address, value): {records["out_of_map_writes"]}')
    for name, counts in records['max_written_counts'].items():
        if not (isinstance(counts, int) and 0 <= counts <= p_max_counts):
            found.append(f'{source}: channel {name} was written {counts!r} counts '
                         f'(allowed: an integer 0..{p_max_counts})')
    kpa = [c / records['counts_per_kpa'] for c in records['max_written_counts'].values() if isinstance(c, int)]
    if not all(math.isfinite(v) and v <= records['p_max_kpa'] for v in kpa):
        found.append(f'{source}: largest written pressure {max(kpa)} kPa is above p_max {records["p_max_kpa"]} kPa')
    return found
