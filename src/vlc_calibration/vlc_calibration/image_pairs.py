"""The stereo image pairs of a calibration folder.

Two layouts:

* ``pairs``: one file per camera, ``left<key>.<ext>`` and ``right<key>.<ext>`` with the
  same key, e.g. ``left_001.png``/``right_001.png`` or ``camera_calibration``'s
  ``left-0000.png``/``right-0000.png``;
* ``side-by-side``: one file per pair, the left image in the left half (e.g. 2560×720
  for two 1280×720 cameras).

``auto`` takes ``pairs`` when the folder holds a ``left*``/``right*`` image, else
``side-by-side``. Images are read as 8-bit grey.
"""
from dataclasses import dataclass
import pathlib
import re

import cv2

IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.bmp', '.pgm', '.ppm', '.tif', '.tiff')
LAYOUTS = ('auto', 'pairs', 'side-by-side')
_SIDE = re.compile(r'^(left|right)(.*)$', re.IGNORECASE)


class InputError(ValueError):
    """Unusable input of a command (the commands exit with status 2)."""


@dataclass
class ImagePair:
    """One stereo pair: ``name`` for messages, the file(s) it is read from."""

    name: str
    left_path: pathlib.Path
    right_path: pathlib.Path = None          # None: side by side in left_path

    def load(self):
        """(left, right) grey images (H, W) uint8; InputError when unreadable or odd."""
        left = _read(self.left_path)
        if self.right_path is None:
            height, width = left.shape
            if width % 2:
                raise InputError(f'{self.left_path.name}: a side-by-side image must have an '
                                 f'even width, not {width} px')
            return left[:, :width // 2], left[:, width // 2:]
        right = _read(self.right_path)
        if left.shape != right.shape:
            raise InputError(f'size mismatch: {self.left_path.name} is {_size(left)} but '
                             f'{self.right_path.name} is {_size(right)}')
        return left, right


def _size(image):
    return f'{image.shape[1]}x{image.shape[0]} px'


def _read(path):
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f'{path.name}: not a readable image')
    return image


def find_image_pairs(folder, layout='auto'):
    """The image pairs of ``folder`` in name order (list of :class:`ImagePair`).

    Raises InputError for a missing folder, an unknown layout, a folder without images,
    or (``pairs``) a left image without its right image or the reverse.
    """
    folder = pathlib.Path(folder)
    if layout not in LAYOUTS:
        raise InputError(f'unknown layout {layout!r}: expected one of {", ".join(LAYOUTS)}')
    if not folder.is_dir():
        raise InputError(f'{folder}: no such folder')
    images = sorted(p for p in folder.iterdir()
                    if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not images:
        raise InputError(f'{folder}: no images ({", ".join(IMAGE_EXTENSIONS)})')
    sided = {}
    for path in images:
        match = _SIDE.match(path.stem)
        if match:
            sided.setdefault(match.group(1).lower(), {})[match.group(2)] = path
    if layout == 'auto':
        layout = 'pairs' if sided else 'side-by-side'
    if layout == 'side-by-side':
        return [ImagePair(path.name, path) for path in images]
    left, right = sided.get('left', {}), sided.get('right', {})
    alone = sorted([p.name for k, p in left.items() if k not in right]
                   + [p.name for k, p in right.items() if k not in left])
    if alone:
        raise InputError(f'{folder}: images without their other camera\'s image: '
                         f'{", ".join(alone[:10])}' + (' …' if len(alone) > 10 else ''))
    if not left:
        raise InputError(f'{folder}: no left*/right* image pairs')
    return [ImagePair(f'{left[key].name}/{right[key].name}', left[key], right[key])
            for key in sorted(left)]
