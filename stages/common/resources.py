"""What a run will need, checked before it starts: memory and disk; and the threads it lends
OpenCV (``opencv_single_threaded``).

A field of ``length: 1e5``, ``build-map --resolution 0.001`` or ``simulate --frames 1e12`` would
otherwise try to allocate terabytes and die with a MemoryError or the kernel's OOM killer, or
fill the disk. Each stage estimates its need from its inputs (``estimate`` lists what the
bytes are for) and refuses with the estimate when this machine cannot hold it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
from pathlib import Path

from .artifacts import human_bytes
from .errors import DiskFullError, FieldlocError


def available_memory() -> int:
    """Bytes of memory this process can still use: MemAvailable of /proc/meminfo (Linux), else
    the free physical pages."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 1 << 62  # unknown: do not refuse


def check_memory(what: str, estimate: dict[str, float]) -> float:
    """Refuse (FieldlocError) when the sum of ``estimate`` (purpose -> bytes) exceeds the
    available memory; returns the sum."""
    total = float(sum(estimate.values()))
    avail = available_memory()
    if total > avail:
        parts = ", ".join(f"{k} {human_bytes(v)}" for k, v in estimate.items())
        raise FieldlocError(
            f"{what} would need about {human_bytes(total)} of memory ({parts}); this machine"
            f" has {human_bytes(avail)} available")
    return total


def check_disk(what: str, folder: str | Path, need: float, *,
               target: str | Path | None = None) -> None:
    """Refuse when ``need`` bytes do not fit on the disk holding ``folder``. With ``target``
    (the file a run that already kept work would write next), as the full disk's own line
    (DiskFullError naming ``target``: the CLI adds what the run kept for a rerun)."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if need > free and target is not None:
        raise DiskFullError(target, f"it needs about {human_bytes(need)}, {folder} has"
                                    f" {human_bytes(free)} free")
    if need > free:
        raise FieldlocError(
            f"{what} would write about {human_bytes(need)}; {folder} has {human_bytes(free)}"
            " free")


# OpenCV's thread pool while frames are worked on one at a time (opencv_single_threaded); the
# count of those blocks running (threads of one process may extract at once) and the pool's
# size before the first began
_OPENCV_LOCK = threading.Lock()
_opencv_blocks = 0
_opencv_threads = 0


@contextlib.contextmanager
def opencv_single_threaded():
    """OpenCV without its thread pool inside the block (restored when the last such block of
    the process ends). A frame's OpenCV calls are small (a colour conversion of a 752 x 480
    image, a 3 x 3 blur on 94 x 60 cells): handing each to a pool of threads costs more CPU
    than the call itself and saves no wall time (docs/results.md, images to poses), and a
    batch already runs one stream of frames per core."""
    import cv2

    global _opencv_blocks, _opencv_threads
    with _OPENCV_LOCK:
        if _opencv_blocks == 0:
            _opencv_threads = cv2.getNumThreads()
            cv2.setNumThreads(1)
        _opencv_blocks += 1
    try:
        yield
    finally:
        with _OPENCV_LOCK:
            _opencv_blocks -= 1
            if _opencv_blocks == 0:
                cv2.setNumThreads(_opencv_threads)
