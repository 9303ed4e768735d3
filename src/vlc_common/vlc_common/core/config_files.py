"""Where a package's shipped configuration files are: ``share/<package>/config/``."""
import pathlib

#: ``src/`` of the source tree (``src/vlc_common/vlc_common/core/`` → three levels up).
_SOURCE_TREE = pathlib.Path(__file__).resolve().parents[3]


def config_path(package, name):
    """``share/<package>/config/<name>`` of the installed package (ament index), else the
    source tree's ``src/<package>/config/<name>``; the path may not exist.
    """
    try:
        from ament_index_python.packages import get_package_share_directory
        path = pathlib.Path(get_package_share_directory(package)) / 'config' / name
        if path.exists():
            return path
    except (ImportError, LookupError, ValueError):
        pass
    return _SOURCE_TREE / package / 'config' / name
