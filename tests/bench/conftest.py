"""A bench script as a module for the tests of tests/bench that name it in ``BENCH_SCRIPT``."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench_script(request):
    """bench/<the test module's BENCH_SCRIPT> imported (bench/ on the path while it loads: its sibling imports)."""
    name = request.module.BENCH_SCRIPT
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        spec = importlib.util.spec_from_file_location(f"bench_{Path(name).stem}", ROOT / "bench" / name)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod   # a dataclass looks its module up
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(ROOT / "bench"))
    return mod
