"""What a run will need, checked before it starts: memory and disk.

A field of ``length: 1e5``, ``build-map --resolution 0.001`` or ``simulate --frames 1e12`` would
otherwise try to allocate terabytes and die with a MemoryError or the kernel's OOM killer, or
fill the disk. Each stage estimates its need from its inputs (``estimate`` lists what the
bytes are for) and refuses with the estimate when this machine cannot hold it.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from .artifacts import human_bytes
from .errors import FieldlocError


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


def check_disk(what: str, folder: str | Path, need: float) -> None:
    """Refuse when ``need`` bytes do not fit on the disk holding ``folder``."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if need > free:
        raise FieldlocError(
            f"{what} would write about {human_bytes(need)}; {folder} has {human_bytes(free)}"
            " free")
