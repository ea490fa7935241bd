"""Every difference between the pymodbus versions the package supports, in one place.

Supported: 3.6.9 (Ubuntu 24.04's python3-pymodbus, what rosdep installs for ROS 2 Kilted)
up to the 3.16 line (the newest on the package index when this was written); package.xml
states the same range. Only the synchronous TCP client is used: the mock PLC (modbus.py) is
a plain asyncio Modbus TCP server of its own, so the server and datastore APIs, which changed
most between these versions (ModbusSlaveContext -> ModbusDeviceContext in 3.10, the datastore
deprecated in 3.16), are never imported.

What differs for the client:
- the unit id keyword: ``slave=`` up to 3.9, ``device_id=`` from 3.10 (``slave=`` removed);
- ``count`` is positional in 3.6 and keyword-only from 3.8: always passed by keyword here;
- a request that got no answer: 3.6 returns a ModbusIOException (and closes the socket), 3.9+
  raise it (and keep the socket): callers treat an error response without an exception code
  like a raised exception and open the connection themselves before a request.
"""
from __future__ import annotations

import inspect

import pymodbus
from pymodbus.client import ModbusTcpClient

__all__ = ['PYMODBUS_VERSION', 'SUPPORTED', 'exception_code', 'is_open', 'make_client', 'request',
           'unit_keyword']

PYMODBUS_VERSION: str = pymodbus.__version__
#: The supported range, [lowest, first unsupported): also in package.xml.
SUPPORTED = ('3.6.9', '3.17')


def _unit_keyword() -> str:
    params = inspect.signature(ModbusTcpClient.read_holding_registers).parameters
    if 'device_id' in params:
        return 'device_id'
    if 'slave' in params:
        return 'slave'
    raise ImportError(f'pymodbus {PYMODBUS_VERSION}: read_holding_registers takes neither '
                      f'device_id= nor slave=; supported pymodbus: {SUPPORTED[0]} <= version < '
                      f'{SUPPORTED[1]}')


#: The keyword that carries the Modbus unit id in this pymodbus.
unit_keyword = _unit_keyword()


def make_client(host: str, port: int, timeout_s: float) -> ModbusTcpClient:
    """A synchronous TCP client; retries=0: a command retried after a timeout would arrive late
    and out of order (the caller's next cycle sends a fresh one instead)."""
    return ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)


def request(client: ModbusTcpClient, method: str, *args, unit_id: int, count: int | None = None):
    """Call ``client.<method>(*args)`` for unit ``unit_id`` (and ``count`` registers)."""
    kwargs = {unit_keyword: unit_id}
    if count is not None:
        kwargs['count'] = count
    return getattr(client, method)(*args, **kwargs)


def exception_code(response) -> int | None:
    """The Modbus exception code of an exception response (1..255), else None."""
    code = getattr(response, 'exception_code', None)
    return int(code) if isinstance(code, int) and code else None


def is_open(client: ModbusTcpClient) -> bool:
    """True while the client's TCP socket is open (pymodbus drops it on a broken connection)."""
    return getattr(client, 'socket', None) is not None
