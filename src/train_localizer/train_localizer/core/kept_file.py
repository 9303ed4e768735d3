"""What the kept files (self-calibration, lamp refinement) share: reading one as a YAML
mapping with errors that name the file, and writing one atomically.
"""
import os
import pathlib
import time

import yaml

from vlc_common.core.config_files import SAFE_LOADER


def read_mapping(path, error):
    """The YAML mapping in ``path``; None if the file does not exist (a first run);
    ``error`` (an exception class) with ``<path>: <problem>`` if it does not parse or is
    not a mapping.
    """
    path = pathlib.Path(path)
    if not path.exists():
        return None
    try:
        data = yaml.load(path.read_text(encoding='utf-8'), Loader=SAFE_LOADER)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise error(f'{path}: does not parse: {exc}') from None
    if not isinstance(data, dict):
        raise error(f'{path}: not a mapping of fields')
    return data


def write_atomically(path, data, header='', **dump_options):
    """``data`` (with a ``written`` UTC time) as YAML in ``path``: a temporary file
    renamed over the old one, so a reader never sees half a file.
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = dict(data, written=time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()))
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(header + yaml.safe_dump(data, sort_keys=False, **dump_options),
                   encoding='utf-8')
    os.replace(tmp, path)
