"""Write aerotri/core/numba_signatures.txt: the numba kernels a demo run (and with ``--suite`` the test suite) calls
and their signatures, which ``make install`` compiles beforehand (``aerotri.core.precompile``).

Runs ``aerotri demo`` (the simulated block and the whole chain, as ``make demo`` does) in this process, in a
temporary folder, then lists the signatures of every cached kernel the toolkit's modules hold. With ``--suite`` the
test suite runs too (``pytest -n auto``, as ``make test``), each test process writing the signatures its tests
called (``tests/conftest.py``, ``AEROTRI_RECORD_NUMBA_SIGNATURES``): the kernels of the commands the demo does not
run (drainage, smoothing, the TIN of the tree rasters, building footprints in the true ortho, ...), which a user's
first such command compiled one after another, as did a clean clone's test run. Kernels only called in a command's
own process (a test starting ``lidarctl`` in a subprocess) are not seen. Run it again when kernels are added or their
argument types change (a missing signature only compiles on its first call, as before;
``tests/aerotri/core/test_precompile.py`` checks every listed kernel still exists):

  .venv/bin/python bench/record_numba_signatures.py            # about 3 min with warm caches
  .venv/bin/python bench/record_numba_signatures.py --suite    # and the suite: about 17 min more
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from aerotri.core.precompile import MANIFEST, loaded_signatures, read_manifest, write_manifest

REPO = Path(__file__).resolve().parents[1]


def suite_signatures(folder: Path) -> list:
    """The signatures the test suite's processes called (``make test``'s pytest options), written into ``folder``."""
    env = dict(os.environ, AEROTRI_RECORD_NUMBA_SIGNATURES=str(folder))
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "auto",
                          "--maxprocesses", "4", "--dist", "worksteal"], cwd=REPO, env=env)
    if run.returncode != 0:
        raise SystemExit(f"the test suite failed (exit {run.returncode}): no signatures written")
    files = sorted(folder.glob("*.txt"))
    if not files:
        raise SystemExit(f"the test processes wrote no signatures into {folder}")
    return [e for f in files for e in read_manifest(f)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", action="store_true", help="the test suite's signatures as well")
    args = parser.parse_args(argv)
    from aerotri.cli import main as cli

    with tempfile.TemporaryDirectory(prefix="numba_signatures_") as tmp:
        try:
            cli(["demo", str(Path(tmp) / "demo")], standalone_mode=False)
        except SystemExit as exc:
            if exc.code not in (0, None):
                raise
        entries = loaded_signatures()
        demo = len(entries)
        if args.suite:
            (Path(tmp) / "suite").mkdir()
            entries += suite_signatures(Path(tmp) / "suite")
    write_manifest(entries, MANIFEST, header=(
        "The numba kernels `aerotri demo`" + (" and the test suite call" if args.suite else " calls") +
        ", with their argument types: `make install` compiles them into\n"
        "their cache (aerotri/core/precompile.py). Written by bench/record_numba_signatures.py" +
        (" --suite" if args.suite else "") + "; do not edit."))
    written = read_manifest(MANIFEST)
    kernels = len({(e.module, e.function) for e in written})
    print(f"{len(written)} signatures of {kernels} kernels ({demo} from the demo) -> {MANIFEST}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
