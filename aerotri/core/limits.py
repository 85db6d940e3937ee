"""Physical limits checked before allocating or writing: memory and disk of this machine, raster grid sizes.

A command whose options ask for more than the machine can hold (``ortho rectify --res-m 0.0005`` over a
block of 300 m frames is an ortho of 4e11 pixels per frame) stops at once with a ``ResourceError``
naming the option and the size it would need, instead of trying to allocate it (a MemoryError, or
the kernel's out-of-memory killer, minutes later).
"""

from __future__ import annotations

import os

from aerotri.core.errors import ResourceError

# GeoTIFF and GDAL count rows and columns with signed 32-bit integers.
MAX_GRID_SIDE_PX = 2**31 - 1
# Pieces (tiles, windows, chunks) a command may cut its work into: each costs a task's overhead (about a
# millisecond of scheduling, reading and writing its border), so far more than this is hours spent on
# overhead: the work of a tile or chunk option must be bounded by the data, not by the option.
MAX_TASKS = 1_000_000
# Worker processes (``--scheduler local:N``) and threads (``--workers``) per core of this machine.
MAX_PROCESSES_PER_CORE = 4
MAX_THREADS_PER_CORE = 16


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity (``taskset``, a batch scheduler's cpuset, a test worker
    pinned to its core), else the machine's cores. The default number of threads of every pool of ours; numba,
    OpenBLAS and OpenCV size their own pools from the same affinity (GDAL's ``ALL_CPUS``: not checked)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this system (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def physical_memory_bytes() -> int:
    """Physical memory of this machine (bytes); 0 when the system does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return 0


def format_bytes(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024.0 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} PiB"


def check_allocation(n_bytes: float, what: str, option: str | None = None, *, hint: str = "",
                     fraction: float = 0.8) -> None:
    """``ResourceError`` when ``what`` would need more than ``fraction`` of the physical memory: refuse before
    allocating rather than fail with a MemoryError (or the out-of-memory killer) minutes later.

    ``option`` names the option that sets the size (e.g. ``--res-m``); the message gives both sizes and ``hint``
    (what to change). 80 %: the process, its libraries and the system need the rest."""
    total = physical_memory_bytes()
    if total and n_bytes > fraction * total:
        hint = f"; {hint}" if hint else f"; change {option}" if option else ""
        raise ResourceError(f"{what} would need {format_bytes(n_bytes)} of memory, more than {fraction:.0%} of this "
                            f"machine's {format_bytes(total)}{hint}", param=option)


def check_disk(n_bytes: float, folder, what: str, option: str | None = None, *, hint: str = "") -> None:
    """``ResourceError`` when ``n_bytes`` exceed the free space on the disk holding ``folder`` (or its nearest
    existing parent): refuse before writing rather than fill the disk."""
    import shutil
    from pathlib import Path

    folder = Path(folder).absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    if n_bytes > free:
        msg = f"{what} would need up to {format_bytes(n_bytes)} of disk, more than the {format_bytes(free)} free in {folder}"
        raise ResourceError(msg + (f"; {hint}" if hint else ""), param=option)


def check_task_count(n_tasks: float, what: str, option: str | None = None, hint: str = "") -> None:
    """``ResourceError`` when ``what`` would be cut into more than ``MAX_TASKS`` pieces (a tile or chunk
    option far too small for the data: the work would never end in practice)."""
    if n_tasks > MAX_TASKS:
        raise ResourceError(f"{what}: {n_tasks:,.0f} pieces, more than the {MAX_TASKS:,} this toolkit cuts work "
                            f"into{f'; {hint}' if hint else ''}", param=option)


def check_workers(n: int, processes: bool, option: str) -> None:
    """``OptionError`` for a number of workers below 1 (nothing would ever run the tasks: a hang) or far above
    the cores of this machine (``MAX_PROCESSES_PER_CORE`` processes, ``MAX_THREADS_PER_CORE`` threads)."""
    from aerotri.core.errors import OptionError

    cores = os.cpu_count() or 1
    top = cores * (MAX_PROCESSES_PER_CORE if processes else MAX_THREADS_PER_CORE)
    kind = "worker processes" if processes else "worker threads"
    if n < 1:
        raise OptionError(f"{option} {n}: at least 1 of the {kind} is needed (none would run the tasks)", param=option)
    if n > top:
        raise OptionError(f"{option} {n}: more {kind} than {top} ({MAX_PROCESSES_PER_CORE if processes else MAX_THREADS_PER_CORE} "
                          f"per core of this machine's {cores})", param=option)


def check_grid(width: float, height: float, what: str, option: str | None = None) -> None:
    """``ResourceError`` when a raster grid is empty or has a side beyond what GeoTIFF/GDAL can index."""
    if not (width >= 1 and height >= 1):
        raise ResourceError(f"{what} is empty ({width:.0f} x {height:.0f} px)", param=option)
    if width > MAX_GRID_SIDE_PX or height > MAX_GRID_SIDE_PX:
        raise ResourceError(f"{what} would be {width:,.0f} x {height:,.0f} px, beyond the {MAX_GRID_SIDE_PX:,} px "
                            f"a GeoTIFF side can have{f'; change {option}' if option else ''}", param=option)
