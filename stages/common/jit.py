"""fieldloc's ``njit``: numba's, with a compiled-kernel cache that may fail to be written.

Every kernel is compiled with ``cache=True`` and numba writes the machine code beside the
source (``__pycache__``) or under NUMBA_CACHE_DIR. On a full disk (or quota) that write
raises OSError out of the first call of the kernel (numba guards it on Windows only), and a
command stopped with a bare "No space left on device" about a disk its output is not on. A
cache that cannot be written costs only the next run's compile time, so here its failure is
logged once (INFO: shown under -v) and the kernel runs as compiled, in memory.

Every module of ``stages`` takes ``njit`` from here, so the guard is in place before any
kernel compiles, in the CLI's process and in batch's workers alike.
"""

from __future__ import annotations

import functools
import logging

from numba import njit

try:  # numba's internal cache class: where a numba release moves it, the guard is skipped
    from numba.core.caching import Cache
except ImportError:  # pragma: no cover (every numba the project supports has it)
    Cache = None

log = logging.getLogger(__name__)

__all__ = ["njit"]

_told = False  # the cache's failure is told once per process, not once per kernel


def _save_or_skip(save):
    @functools.wraps(save)
    def save_overload(self, sig, data):
        global _told
        try:
            save(self, sig, data)
        except OSError as e:
            if not _told:
                _told = True
                log.info("numba's kernel cache in %s cannot be written (%s): kernels are"
                         " compiled for this run only", self.cache_path, e.strerror or e)
    save_overload._fieldloc_guard = True
    return save_overload


_save = getattr(Cache, "save_overload", None)
if _save is not None and not getattr(_save, "_fieldloc_guard", False):
    Cache.save_overload = _save_or_skip(_save)
