"""Where a package's shipped configuration files are: ``share/<package>/config/``; and
the YAML loader and dumper the packages read and write their files with.
"""
import pathlib

import yaml

#: libyaml's safe loader and dumper where PyYAML has them (else the pure-Python ones): the
#: same data and the same text as ``yaml.safe_load``/``yaml.safe_dump``, several times less
#: CPU (a 200-lamp map: 8x to load, 4x to write; a bag's metadata rewritten at every flush).
SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
SAFE_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)

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
