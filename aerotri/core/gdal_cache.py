"""GDAL's block cache of a stage: one size per process, set by the stage's calling thread.

GDAL has one block cache per process. ``rasterio.Env(GDAL_CACHEMAX=n)`` sets it with ``GDALSetCacheMax64(n)``
(n in bytes, whatever GDAL's config option would mean by a small number: ``GDAL_CACHEMAX=256`` is 256
bytes, not 256 MB), which flushes the blocks of every open dataset down to the new size, and sets it back
on exit. Entered inside tasks that run on threads (``ortho rectify``'s frame tasks did), that is unsafe
twice over: the exits of overlapping tasks restore each other's values, so the process keeps the 256 bytes
for good (every later read and write of any dataset then evicts other datasets' blocks), and one thread
flushes the dirty blocks of a GeoTIFF another thread is writing, which GDAL does not support (corrupt
blocks, OSGeo/gdal#2011; threads waiting on each other for good, OSGeo/gdal#3848). The suite hung in
tests/ortho/test_block_atomic.py that way (every thread in a futex wait, rectify temporaries open).

So every stage that writes rasters (the ortho stages, the simulator, ``lidarctl rasters``) sets the cache
once, in bytes, from the thread that calls it, around the whole stage (before its worker threads start,
after they have ended), with ``stage_block_cache``, never inside a task or per writer. Other GDAL options
(``GDAL_PAM_ENABLED``, ...) are per thread in rasterio (a worker thread's ``rasterio.Env`` sets thread-local
options) and may still be set by a task.

A stage's size is at most an eighth of the memory the process may use (``aerotri.core.limits.cache_bytes``): the
256 MiB of ``lidarctl rasters`` were filled by its working rasters' blocks and, with the libraries' 250 MB, took the
demo's rasters past a 600 MiB batch job's limit at any tile size (killed by the kernel); 75 MiB there.
"""

from __future__ import annotations

import contextlib

MiB = 2 ** 20


@contextlib.contextmanager
def stage_block_cache(max_bytes: int):
    """GDAL's block cache at ``max_bytes`` (bytes; at most an eighth of the memory the process may use) while the
    block runs, the previous size after it. Enter it in the thread that calls a stage, around the stage, never in a
    task on a worker thread (module doc)."""
    import rasterio

    from aerotri.core.limits import cache_bytes

    if max_bytes < MiB:  # a size in MB passed by mistake would leave the cache useless (module doc)
        raise ValueError(f"GDAL block cache of {max_bytes} bytes: expected bytes (at least 1 MiB)")
    with rasterio.Env(GDAL_CACHEMAX=max(MiB, cache_bytes(max_bytes))):
        yield
