"""A namespaced suit names its own PLC: the launch files' and the process graph's one rule.

A second suit on the domain runs in a namespace (`namespace:=suit_b`); its plc_output, left with
the parameter file's address (127.0.0.1:1502, the first suit's), would drive the first suit's
PLC. So a launch (or a Graph) with a namespace refuses to start unless the address is given for
it: plc_host or plc_port for the lab launch, plc_port for the simulated ones (their mock PLC is
on this machine). No launch import here, so the main suite tests it (test_plc_stop.py).
"""
from __future__ import annotations

from typing import Mapping


def require_own_plc(namespace: str, given: Mapping[str, object], where: str = 'launch argument') -> None:
    """ValueError naming the arguments when `namespace` is set and none of `given` (the PLC
    address arguments, name -> value as given; '' or None: left to the parameter files) is."""
    ns = namespace.strip().strip('/')
    if not ns or any(value not in ('', None) for value in given.values()):
        return
    names = ' or '.join(f'{name}:=...' for name in given)
    raise ValueError(f'{where} namespace:={namespace}: a suit in a namespace needs its own PLC address; give '
                     f'{names} (the parameter files\' address is the root suit\'s PLC)')
