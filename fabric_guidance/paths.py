"""Where the package's share files (config/, launch/) are, in a workspace or a checkout."""
from __future__ import annotations

from pathlib import Path

PACKAGE = 'fabric_guidance'


def share_dir() -> Path:
    """The installed share/fabric_guidance in a ROS workspace, else the source checkout."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            return Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH unset (no workspace)
            pass
    except ImportError:
        pass
    return Path(__file__).resolve().parent.parent


def config_path(name: str) -> Path:
    """A file under config/ (e.g. 'hardware/channel_map.yaml')."""
    return share_dir() / 'config' / name


def resolve(value: str, default_name: str) -> Path:
    """A file parameter: '' is the package's config/<default_name>; '~' is expanded; a relative
    path is taken from the package share (so parameter files work from any directory)."""
    if not value:
        return config_path(default_name)
    path = Path(value).expanduser()
    return path if path.is_absolute() else share_dir() / path


def node_parameters(path: str | Path, node: str) -> dict:
    """The `ros__parameters` a parameter file gives a node of that name in any namespace: the
    entries keyed `/**`, `/**/<node>`, `<node>` or `/<node>`, merged in the file's order (rcl's
    for the package's files, which key each node once). `path` relative: under config/."""
    import yaml
    path = Path(path)
    data = yaml.safe_load((path if path.is_absolute() else config_path(str(path))).read_text()) or {}
    merged: dict = {}
    for key, entry in data.items():
        if str(key) in ('/**', f'/**/{node}', node, f'/{node}') and isinstance(entry, dict):
            merged.update(entry.get('ros__parameters') or {})
    return merged
