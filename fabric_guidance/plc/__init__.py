"""The PLC layer: register map, Modbus TCP client, mock PLC. No ROS code here.

register_map  which register carries which channel; kPa <-> counts, clamped to p_max
regulator     the PLC's regulator lag and heartbeat watchdog, simulated in plain Python
modbus        PlcClient, the client the package drives the suit with (pymodbus)
mock_server   MockPlcServer: the PLC contract, served without pymodbus (tests, the demo)
pymodbus_compat  the only module that imports pymodbus: every version difference

The pymodbus-backed names are imported lazily, so the register map and the simulation can
be used (and tested) where pymodbus is not installed.
"""
from .register_map import ChannelRegisters, PlcEndpoint, PlcLayout, RegisterMap, RegisterMapError
from .regulator import FirstOrderLag, RegulatorSim, ScanResult, Watchdog

_MODBUS_NAMES = ('MockPlcServer', 'PlcClient', 'PlcLinkError', 'PlcNoAnswerError',
                 'PlcRefusedError')

__all__ = ['ChannelRegisters', 'FirstOrderLag', 'MockPlcServer', 'PlcClient', 'PlcEndpoint',
           'PlcLayout', 'PlcLinkError', 'PlcNoAnswerError', 'PlcRefusedError', 'RegisterMap',
           'RegisterMapError', 'RegulatorSim', 'ScanResult', 'Watchdog']


def __getattr__(name: str):
    # PEP 562: import pymodbus only when a Modbus name is actually used.
    if name == 'MockPlcServer':
        from .mock_server import MockPlcServer
        return MockPlcServer
    if name in _MODBUS_NAMES:
        from . import modbus
        return getattr(modbus, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
