"""Disk memo of the renderer's start-up arrays (ROS-free).

A camera node builds, before its first frame, arrays that depend only on its
installation and seed: the lens maps of a raw camera (the undistortion of every sensor
pixel by Newton's method, ~0.8 CPU-s per camera) and the bank of noisy background frames
(~0.05 CPU-s per frame, 16 or 32 of them). An evaluation starts a camera node per
scenario and draws the same few installations again and again (seeds 1–10 over 20
static points and six speeds), so each scenario paid that work again: 0.75 CPU-s of the
ideal camera's 1.5 per static trial, ~2 of the realistic camera's 3.4.

:func:`cached` keeps such arrays in a directory (``set_directory``; the node's
``precompute_cache_dir`` parameter, unset = off, the default): one ``.npz`` per key,
the key a SHA-256 of the inputs' exact ``repr`` (floats round-trip), of any input arrays'
bytes, and of the source files of the code that computes them, so a changed model never
reads an old entry. A hit returns the very arrays the computation returns (bit for bit:
``test_precompute_cache``); an unreadable entry is computed again and replaced; a
directory that cannot be written leaves the node computing as before. Entries are
written to a temporary file and renamed, so two nodes filling the same key at once each
read a whole file.
"""
import hashlib
import os
import pathlib
import zipfile

import numpy as np

#: Bumped when the layout of an entry changes.
CACHE_VERSION = 1

_directory = None
_source_digests = {}


def set_directory(path):
    """Cache entries in ``path`` (created when first written); '' or None: off."""
    global _directory
    _directory = pathlib.Path(path) if path else None


def source_digest(*modules):
    """SHA-256 of the source files of ``modules`` (computed once per module)."""
    h = hashlib.sha256()
    for module in modules:
        path = module.__file__
        if path not in _source_digests:
            _source_digests[path] = hashlib.sha256(pathlib.Path(path).read_bytes()).digest()
        h.update(_source_digests[path])
    return h.hexdigest()


def array_digest(*arrays):
    """SHA-256 of the arrays' dtype, shape and bytes."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.data)
    return h.hexdigest()


def cached(kind, key, compute):
    """``compute()`` — a dict of name: ndarray — or the entry of an earlier call with the
    same ``kind`` and ``key`` (any value with an exact ``repr``: numbers, strings,
    tuples, dataclasses, digests; or a function returning it, called only when the memo
    is on, so digests of large arrays cost nothing without it).
    """
    if _directory is None:
        return compute()
    if callable(key):
        key = key()
    name = hashlib.sha256(repr((CACHE_VERSION, kind, key)).encode()).hexdigest()[:40]
    path = _directory / f'{kind}-{name}.npz'
    try:
        with np.load(path, allow_pickle=False) as entry:
            return {k: entry[k] for k in entry.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        pass
    arrays = compute()
    tmp = path.with_name(f'.{path.name}.{os.getpid()}.tmp')
    try:
        _directory.mkdir(parents=True, exist_ok=True)
        with open(tmp, 'wb') as stream:
            np.savez(stream, **arrays)
        os.replace(tmp, path)
    except OSError:
        try:
            tmp.unlink()
        except OSError:
            pass
    return arrays
