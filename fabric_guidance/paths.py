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
