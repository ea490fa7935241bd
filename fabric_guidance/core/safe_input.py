"""Reading files from outside safely: one YAML loader for every file the package reads, one
bound on what an error message prints of a value, one check of a wearer's name.

- load_yaml / parse_yaml: PyYAML's safe loader that refuses anchors and aliases (a 400-byte
  alias bomb expands to gigabytes once something walks or prints it), refuses files larger
  than a bound, and reports any failure as one InputFileError line naming the file.
- excerpt(value): a repr of at most a few dozen characters, whatever the value holds.
- check_wearer(name): a wearer's name becomes a file name (<wearer>.yaml, <wearer>-fit.png):
  letters, digits, '_', '-', '.', no leading dot, at most 64 characters.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
import re
import reprlib

import yaml

#: No file the package reads is near this (a calibration is ~4 kB, a scene ~10 kB).
MAX_FILE_BYTES = 4 * 1024 * 1024
#: What an error message shows of a value at most.
EXCERPT_CHARS = 60
WEARER_PATTERN = re.compile(r'[A-Za-z0-9][A-Za-z0-9_.-]{0,63}')
WEARER_RULE = ('must be a name of 1-64 letters, digits, "_", "-" or "." starting with a letter '
               'or digit (it becomes a file name)')


class InputFileError(ValueError):
    """A file that cannot be read or parsed: one line naming the file and the reason."""


class _Repr(reprlib.Repr):
    def __init__(self):
        super().__init__()
        self.maxlevel, self.maxdict, self.maxlist, self.maxtuple = 2, 4, 4, 4
        self.maxset = self.maxfrozenset = self.maxdeque = self.maxarray = 4
        self.maxstring = self.maxother = self.maxlong = EXCERPT_CHARS


_REPR = _Repr()


def excerpt(value, limit: int = EXCERPT_CHARS) -> str:
    """repr(value) cut to about `limit` characters on one line, without walking all of a big or
    deeply nested value (reprlib stops at a few items and two levels)."""
    try:
        text = _REPR.repr(value)
    except Exception:  # a repr that fails is still a value to name
        text = f'<{type(value).__name__}>'
    text = ' '.join(text.split())
    return text if len(text) <= limit else text[:limit - 3] + '...'


def got(mapping, key) -> str:
    """How an error names what a field held: 'the field is missing' when the mapping has no
    such key (not "got None", which reads as a null written in the file), else 'got <excerpt>'."""
    if isinstance(mapping, Mapping) and key not in mapping:
        return 'the field is missing'
    return f'got {excerpt(mapping.get(key) if isinstance(mapping, Mapping) else None)}'


class _NoAliasLoader(yaml.SafeLoader):
    """Safe loading; an anchor or alias anywhere is an error (no file of the package needs one).
    The pure-Python loader: libyaml's composes in C, past this check."""

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, 'anchor', None) is not None:
            mark = event.start_mark
            raise yaml.YAMLError(f'anchors and aliases are not accepted (line {mark.line + 1})')
        return super().compose_node(parent, index)


def parse_yaml(text: str | bytes, source: str):
    """YAML text -> Python data, or InputFileError('cannot read <source>: <reason>') on one line."""
    if isinstance(text, bytes):
        try:
            text = text.decode('utf-8')
        except UnicodeDecodeError as exc:
            raise InputFileError(f'cannot read {source}: not UTF-8 text (byte {exc.start})') from None
    if len(text) > MAX_FILE_BYTES:
        raise InputFileError(f'cannot read {source}: larger than {MAX_FILE_BYTES} bytes')
    try:
        return yaml.load(text, Loader=_NoAliasLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark is not None else ''
        raise InputFileError(f'cannot read {source}: not valid YAML{where}: {excerpt(exc.problem, 80)}') from None
    except yaml.YAMLError as exc:
        raise InputFileError(f'cannot read {source}: not valid YAML: {excerpt(str(exc), 80)}') from None
    except (ValueError, OverflowError, RecursionError) as exc:
        # int() refusing a huge digit string, a timestamp out of range, nesting too deep
        raise InputFileError(f'cannot read {source}: unusable value: {excerpt(str(exc), 80)}') from None


def load_yaml(path: str | Path, what: str = 'file', error: type[ValueError] | None = None):
    """Read and parse a YAML file; InputFileError (or `error`, the caller's own kind) naming
    `what` and the path on any failure."""
    if error is not None:
        try:
            return load_yaml(path, what)
        except InputFileError as exc:
            raise error(str(exc)) from None
    path = Path(path)
    source = f'{what} {path}'
    try:
        with open(path, 'rb') as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise InputFileError(f'cannot read {source}: {exc.strerror or exc}') from None
    if len(data) > MAX_FILE_BYTES:
        raise InputFileError(f'cannot read {source}: larger than {MAX_FILE_BYTES} bytes')
    return parse_yaml(data, source)


def check_wearer(name, source: str = 'wearer') -> str:
    """The name unchanged when it is safe as a file name; ValueError naming `source` otherwise."""
    if not isinstance(name, str) or not WEARER_PATTERN.fullmatch(name):
        raise ValueError(f'{source} {WEARER_RULE}, got {excerpt(name)}')
    return name
