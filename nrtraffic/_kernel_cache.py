"""Keeps numba's on-disk cache of the compiled kernels consistent with the sources.

numba keys a cached function by its own file only: after an edit to a module that a kernel calls
(``vehicle/bicycle.py`` under ``control/batch.py``, say), the stale machine code of the caller would
still be loaded. Here a digest of every source file of the package is kept beside the caches; when
it differs, every cache file of the package is removed before anything is compiled or loaded, so
the next call recompiles. Runs once, when the package is imported.

:func:`announce` says so on stderr before a run compiles them (the first run after installing or
editing the package: about 20-40 s).
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

_ROOT = Path(__file__).resolve().parent
_STAMP = _ROOT / "__pycache__" / "kernel_sources.sha256"
NOTICE = "compiling kernels (once, about 20-40 s)"
_announced = False


def _digest() -> str:
    h = hashlib.sha256()
    for path in sorted(_ROOT.rglob("*.py")):
        h.update(str(path.relative_to(_ROOT)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def ensure_fresh() -> None:
    """Remove numba cache files (``*.nbi``, ``*.nbc``) of the package if any source changed since
    they were written. Best effort: a read-only installation is left as it is."""
    try:
        digest = _digest()
        if _STAMP.is_file() and _STAMP.read_text() == digest:
            return
        for pattern in ("*.nbi", "*.nbc"):
            for f in _ROOT.rglob(pattern):
                f.unlink(missing_ok=True)
        _STAMP.parent.mkdir(exist_ok=True)
        tmp = _STAMP.with_suffix(f".{id(digest)}.tmp")
        tmp.write_text(digest)
        tmp.replace(_STAMP)
    except OSError:
        pass


def compiled() -> bool:
    """Whether numba's on-disk cache holds the run's main kernel (``control/batch.py``'s
    ``advance``, which calls the others): its index file exists where numba looks for it (beside
    the source, or under ``NUMBA_CACHE_DIR`` or the user's cache where the package is read-only)."""
    import os

    from numba import config

    from nrtraffic.control import batch

    if config.DISABLE_JIT:  # (NUMBA_DISABLE_JIT=1: nothing is compiled)
        return True
    try:
        return os.path.isfile(batch.advance._cache._cache_file._index_path)
    except AttributeError:  # another numba's layout: the package's own __pycache__
        return any((_ROOT / "control" / "__pycache__").glob("batch.advance-*.nbi"))


def announce(file=None) -> bool:
    """Print :data:`NOTICE` on ``file`` (stderr) when the kernels are not compiled yet
    (:func:`compiled`), once per process; returns whether it did."""
    global _announced
    if _announced or compiled():
        return False
    _announced = True
    print(NOTICE, file=file or sys.stderr, flush=True)
    return True


def quiet() -> None:
    """No :func:`announce` in this process (a sweep's worker: the sweep has said it)."""
    global _announced
    _announced = True
