"""Physical limits checked before allocating or writing: memory and disk of this machine (or of the process's
cgroup: a container's or a batch job's CPU and memory limits), raster grid sizes.

A command whose options ask for more than the machine can hold (``ortho rectify --res-m 0.0005`` over a
block of 300 m frames is an ortho of 4e11 pixels per frame) stops at once with a ``ResourceError``
naming the option and the size it would need, instead of trying to allocate it (a MemoryError, or
the kernel's out-of-memory killer, minutes later).
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

from aerotri.core.errors import ResourceError

# GeoTIFF and GDAL count rows and columns with signed 32-bit integers.
MAX_GRID_SIDE_PX = 2**31 - 1
# Pieces (tiles, windows, chunks) a command may cut its work into: each costs a task's overhead (about a
# millisecond of scheduling, reading and writing its border), so far more than this is hours spent on
# overhead: the work of a tile or chunk option must be bounded by the data, not by the option.
MAX_TASKS = 1_000_000
# Worker processes (``--scheduler local:N``) and threads (``--workers``) per core this process may use (``usable_cores``).
MAX_PROCESSES_PER_CORE = 4
MAX_THREADS_PER_CORE = 16


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity (``taskset``, a batch scheduler's cpuset, a test worker
    pinned to its core), else the machine's cores; fewer under a cgroup CPU quota (a container started with
    ``--cpus 2``, a Kubernetes CPU limit, a Slurm job), rounded up as ``nproc`` does. The default number of threads
    of every pool of ours; numba, OpenBLAS and OpenCV are told the same (``limit_library_threads``); GDAL's
    ``ALL_CPUS`` reads the affinity and the quota itself."""
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this system (macOS, Windows)
        cores = max(1, os.cpu_count() or 1)
    quota = _own_cpu_limit()
    return cores if quota is None else max(1, min(cores, math.ceil(quota - 1e-9)))


def physical_memory_bytes() -> int:
    """Physical memory of this machine (bytes); 0 when the system does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return 0


def usable_memory_bytes() -> int:
    """The memory this process may use (bytes): the machine's, or less under a cgroup memory limit (a container's
    ``--memory``, a batch job's); 0 when the system says neither. What the checks before allocating and the
    in-memory choices compare with: past a cgroup's limit the kernel kills the process, however much the machine
    has."""
    total = physical_memory_bytes()
    limit = _own_memory_limit()
    if limit is None:
        return total
    return min(total, limit) if total else limit


def _cgroup_paths(proc_cgroup: Path) -> dict[str, str]:
    """``/proc/self/cgroup`` as {controller: path}; the unified (v2) hierarchy under the key ``""``."""
    paths: dict[str, str] = {}
    try:
        text = proc_cgroup.read_text()
    except OSError:
        return paths
    for line in text.splitlines():
        parts = line.split(":", 2)
        if len(parts) == 3:
            for controller in parts[1].split(","):
                paths[controller] = parts[2]
    return paths


def _cgroup_folders(mount: Path, path: str) -> list[Path]:
    """The folders of a cgroup and of its ancestors up to the mount's root, the cgroup's first. A container sees
    its own cgroup as the mount's root while ``/proc/self/cgroup`` names it by the host's path: a path not under the
    mount is read from the root."""
    folder = mount / path.strip("/")
    if not folder.is_dir():
        return [mount] if mount.is_dir() else []
    out = [folder]
    while folder != mount:
        folder = folder.parent
        out.append(folder)
    return out


def _unified_mount(root: Path) -> Path:
    """Where the unified (v2) hierarchy is mounted: ``root`` itself on a v2 system, ``root/unified`` on a hybrid one."""
    return root if (root / "cgroup.controllers").is_file() else root / "unified"


def _read_first_line(path: Path) -> str | None:
    try:
        return path.read_text().split("\n", 1)[0].strip()
    except (OSError, UnicodeDecodeError):
        return None


def cgroup_cpu_limit(proc_cgroup: str | Path = "/proc/self/cgroup", root: str | Path = "/sys/fs/cgroup") -> float | None:
    """Cores of CPU time this process's cgroups allow per period (quota / period; the lowest over the cgroup and
    its ancestors), None when none sets a quota. cgroup v2: ``cpu.max`` ("max 100000" or "200000 100000"); v1:
    ``cpu.cfs_quota_us`` (-1 without a quota) over ``cpu.cfs_period_us``."""
    proc_cgroup, root = Path(proc_cgroup), Path(root)
    paths = _cgroup_paths(proc_cgroup)
    limits = []
    if "" in paths:  # v2 (or the unified hierarchy of a hybrid system)
        mount = _unified_mount(root)
        for folder in _cgroup_folders(mount, paths[""]):
            line = _read_first_line(folder / "cpu.max")
            if line:
                quota, _, period = line.partition(" ")
                if quota != "max" and _is_positive_number(quota) and _is_positive_number(period or "100000"):
                    limits.append(float(quota) / float(period or "100000"))
    if "cpu" in paths:  # v1: the cpu controller, mounted alone or with cpuacct
        for name in ("cpu", "cpu,cpuacct", "cpuacct,cpu"):
            mount = root / name
            if not mount.is_dir():
                continue
            for folder in _cgroup_folders(mount, paths["cpu"]):
                quota, period = (_read_first_line(folder / f) for f in ("cpu.cfs_quota_us", "cpu.cfs_period_us"))
                if quota and period and _is_positive_number(quota) and _is_positive_number(period):
                    limits.append(float(quota) / float(period))
            break
    return min(limits) if limits else None


def cgroup_memory_limit(proc_cgroup: str | Path = "/proc/self/cgroup", root: str | Path = "/sys/fs/cgroup") -> int | None:
    """Bytes of memory this process's cgroups allow (the lowest over the cgroup and its ancestors), None when none
    sets a limit. cgroup v2: ``memory.max`` ("max" without one); v1: ``memory.limit_in_bytes`` (a number near
    2**63 without one)."""
    proc_cgroup, root = Path(proc_cgroup), Path(root)
    paths = _cgroup_paths(proc_cgroup)
    limits = []
    if "" in paths:
        mount = _unified_mount(root)
        for folder in _cgroup_folders(mount, paths[""]):
            line = _read_first_line(folder / "memory.max")
            if line and line.isdigit():
                limits.append(int(line))
    if "memory" in paths:
        for folder in _cgroup_folders(root / "memory", paths["memory"]):
            line = _read_first_line(folder / "memory.limit_in_bytes")
            if line and line.isdigit() and int(line) < 2**62:  # "unlimited" is the largest page multiple below 2**63
                limits.append(int(line))
    return min(limits) if limits else None


@functools.cache
def _own_cpu_limit() -> float | None:
    """``cgroup_cpu_limit`` of this process, read once (a pool is sized many times a run)."""
    return cgroup_cpu_limit()


@functools.cache
def _own_memory_limit() -> int | None:
    """``cgroup_memory_limit`` of this process, read once."""
    return cgroup_memory_limit()


def _is_positive_number(text: str) -> bool:
    try:
        return float(text) > 0
    except ValueError:
        return False


def limit_library_threads(environ=None) -> None:
    """Under a cgroup CPU quota below the cores this process may run on, tell the libraries that size their thread
    pools from the affinity (numba, OpenMP, OpenBLAS) to use ``usable_cores`` threads: with one thread per
    core of a 64-core host in a container allowed 2 cores, each parallel loop spends its quota in a few ms and is
    throttled for the rest of every period. A variable set by the user is kept. Called when the packages are
    imported, before numba or numpy read them (``environ``: ``os.environ``)."""
    if _own_cpu_limit() is None:
        return
    environ = os.environ if environ is None else environ
    n = str(usable_cores())
    for name in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        environ.setdefault(name, n)


def format_bytes(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024.0 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024.0
    return f"{n:.1f} PiB"


def resident_bytes() -> int:
    """The memory this process holds now and cannot give back (bytes): its resident set less the pages of files
    (libraries' code, files read), which the kernel drops under a limit (``/proc/self/statm``: resident - shared;
    ``RssAnon`` of ``/proc/self/status``); 0 where the system does not say. The libraries' data (70-140 MB once
    numpy, numba, GDAL and PROJ are imported) and what a stage has read so far."""
    try:
        with open("/proc/self/statm") as fh:
            fields = fh.read().split()
        return max(0, int(fields[1]) - int(fields[2])) * int(os.sysconf("SC_PAGE_SIZE"))
    except (OSError, ValueError, IndexError, AttributeError):
        return 0


def cache_bytes(max_bytes: int, share: float = 1 / 8) -> int:
    """A cache's size (bytes): ``max_bytes``, or ``share`` of the memory this process may use when that is less (a
    cache sized for a workstation is most of a 600 MiB batch job's memory)."""
    total = usable_memory_bytes()
    return int(max_bytes) if not total else int(min(max_bytes, share * total))


def check_allocation(n_bytes: float, what: str, option: str | None = None, *, hint: str = "",
                     fraction: float = 0.9, held_bytes: float | None = None) -> None:
    """``ResourceError`` when ``what`` would need, with the memory the process holds already (``held_bytes``, by
    default its anonymous memory now: ``resident_bytes``), more than ``fraction`` of the memory it may use
    (``usable_memory_bytes``): refuse before allocating rather than fail with a MemoryError (or the out-of-memory
    killer) minutes later.

    ``option`` names the option that sets the size (e.g. ``--res-m``); the message gives the sizes and ``hint``
    (what to change). 90 %: the system and the files' pages need the rest (the process's own libraries are in
    what it holds)."""
    total = usable_memory_bytes()
    held = resident_bytes() if held_bytes is None else float(held_bytes)
    if total and n_bytes + held > fraction * total:
        hint = f"; {hint}" if hint else f"; change {option}" if option else ""
        if held > 4 * n_bytes:  # not the size asked for: the hint for it (a coarser grid, strips far apart?) misleads
            hint = ("; it is what the process holds already that leaves too little: give the run more memory "
                    "(or fewer --workers)")
        whose = (f"the {format_bytes(total)} this process's cgroup allows" if total < physical_memory_bytes()
                 else f"this machine's {format_bytes(total)}")
        holds = f" besides the {format_bytes(held)} the process holds already" if held else ""
        raise ResourceError(f"{what} would need {format_bytes(n_bytes)} of memory{holds}, more than "
                            f"{fraction:.0%} of {whose}{hint}", param=option)


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
    the cores this process may use (``usable_cores``: ``MAX_PROCESSES_PER_CORE`` processes, ``MAX_THREADS_PER_CORE``
    threads a core)."""
    from aerotri.core.errors import OptionError

    cores = usable_cores()
    top = cores * (MAX_PROCESSES_PER_CORE if processes else MAX_THREADS_PER_CORE)
    kind = "worker processes" if processes else "worker threads"
    if n < 1:
        raise OptionError(f"{option} {n}: at least 1 of the {kind} is needed (none would run the tasks)", param=option)
    if n > top:
        raise OptionError(f"{option} {n}: more {kind} than {top} ({MAX_PROCESSES_PER_CORE if processes else MAX_THREADS_PER_CORE} "
                          f"per core of the {cores} this process may use)", param=option)


def check_grid(width: float, height: float, what: str, option: str | None = None) -> None:
    """``ResourceError`` when a raster grid is empty or has a side beyond what GeoTIFF/GDAL can index."""
    if not (width >= 1 and height >= 1):
        raise ResourceError(f"{what} is empty ({width:.0f} x {height:.0f} px)", param=option)
    if width > MAX_GRID_SIDE_PX or height > MAX_GRID_SIDE_PX:
        raise ResourceError(f"{what} would be {width:,.0f} x {height:,.0f} px, beyond the {MAX_GRID_SIDE_PX:,} px "
                            f"a GeoTIFF side can have{f'; change {option}' if option else ''}", param=option)


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    """glibc's ``malloc_trim``, None where the C library has none."""
    import ctypes

    try:
        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


def release_freed_memory() -> None:
    """Hand the memory freed so far back to the system (glibc's ``malloc_trim(0)``; nothing without glibc).

    glibc keeps the freed heap memory of every thread's arena for reuse; the phases of a mosaic allocate
    differently sized buffers on several threads, so what one phase freed stayed in the process through the
    next ones: 0.6 GB of a 0.53 GP mosaic's 1.6 GB peak (``bench/results/mosaic_speed_large.json``, "malloc_trim").
    The chain calls it after each stage under a memory limit (``aerotri.chain.runner``)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


def memory_limited() -> bool:
    """Whether a cgroup limits this process's memory below the machine's (a container's or batch job's limit)."""
    limit = _own_memory_limit()
    return limit is not None and limit < (physical_memory_bytes() or limit + 1)


def memory_room_bytes(fraction: float = 0.9) -> float:
    """What this process may still take (bytes): ``fraction`` of the memory it may use (``usable_memory_bytes``)
    less what it holds (``resident_bytes``); infinite where the system does not say. Under a limit the memory freed
    so far is given back first (``release_freed_memory``): glibc keeps what each thread freed in that thread's arena,
    which work on other threads does not reuse (full-size DMC frames matched at 1 GiB: the sparse features' two
    threads kept theirs and the dense features, one at a time, were killed)."""
    total = usable_memory_bytes()
    if not total:
        return math.inf
    if memory_limited():
        release_freed_memory()
    return fraction * total - resident_bytes()
