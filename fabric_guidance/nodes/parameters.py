"""Node parameters: declared with a descriptor that carries the unit and the range, and the
`--params-file` files of a command line checked before rcl reads them."""
from __future__ import annotations

from typing import Any, Sequence

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from ..core.controller_parameters import Parameter
from ..core.safe_input import InputFileError, excerpt, load_yaml


def declare(node: Node, name: str, default: Any, description: str, unit: str = '',
            low: float | int | None = None, high: float | int | None = None, read_only: bool = False) -> Any:
    """Declare a parameter with a descriptor (description, unit, range) and return its value."""
    text = f'{description} [{unit}]' if unit else description
    desc = ParameterDescriptor(description=text, read_only=read_only,
                               additional_constraints=f'unit: {unit}' if unit else '')
    if low is not None and high is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        elif isinstance(default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return node.declare_parameter(name, default, desc).value


def declare_table(node: Node, table: Sequence[Parameter], **values: Any) -> dict[str, Any]:
    """Declare every parameter of a table (core/controller_parameters.py) with its descriptor;
    their values by name. values: a default that is only known at run time (by name)."""
    return {p.name: declare(node, p.name, values.get(p.name, p.default), p.description,
                            '' if p.unit == '-' else p.unit, p.low, p.high, p.read_only)
            for p in table}


def declare_config_file(node: Node, name: str, config_name: str, what: str,
                        read_only: bool = True) -> str:
    """A file parameter whose '' means the package's config/<config_name> (paths.resolve)."""
    return declare(node, name, '', f"{what} (YAML); '' = the package's config/{config_name}",
                   read_only=read_only)


def check_params_files(args: Sequence[str]) -> None:
    """Every `--params-file FILE` of the command line readable, YAML without aliases, and a
    mapping of node names to mappings; InputFileError naming the file otherwise. rcl parses them
    in rclpy.init, before any node exists, and reports a failure as a C traceback."""
    args = list(args)
    for flag, value in zip(args, args[1:]):
        if flag != '--params-file':
            continue
        data = load_yaml(value, 'parameters file')
        if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
            raise InputFileError(f'parameters file {value}: must map node names to '
                                 f'{{ros__parameters: {{...}}}}, got {excerpt(data)}')
