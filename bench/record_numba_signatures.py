"""Write aerotri/core/numba_signatures.txt: the numba kernels a demo run calls and their signatures, which
``make install`` compiles beforehand (``aerotri.core.precompile``).

Runs ``aerotri demo`` (the simulated block and the whole chain, as ``make demo`` does) in this process, in a
temporary folder, then lists the signatures of every cached kernel the toolkit's modules hold. Run it again
when kernels are added or their argument types change (a missing signature only compiles on its first call, as
before; ``tests/aerotri/core/test_precompile.py`` checks every listed kernel still exists):

  .venv/bin/python bench/record_numba_signatures.py            # about 3 min with warm caches
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from aerotri.core.precompile import MANIFEST, loaded_signatures, write_manifest


def main() -> int:
    from aerotri.cli import main as cli

    with tempfile.TemporaryDirectory(prefix="numba_signatures_") as tmp:
        try:
            cli(["demo", str(Path(tmp) / "demo")], standalone_mode=False)
        except SystemExit as exc:
            if exc.code not in (0, None):
                raise
    entries = loaded_signatures()
    write_manifest(entries, MANIFEST, header=(
        "The numba kernels `aerotri demo` calls, with their argument types: `make install` compiles them into\n"
        "their cache (aerotri/core/precompile.py). Written by bench/record_numba_signatures.py; do not edit."))
    kernels = len({(e.module, e.function) for e in entries})
    print(f"{len(entries)} signatures of {kernels} kernels -> {MANIFEST}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
