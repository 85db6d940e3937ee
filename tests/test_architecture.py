"""The layered house (../shared/design/architecture.md) holds: the import-linter contracts of
pyproject.toml (layers, stages independent of each other, no CLI imported but by its command group,
no import cycles within any package) are kept. A change that breaks them fails here, in CI."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_contracts_are_configured():
    contracts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    assert {c["type"] for c in contracts} >= {"layers", "protected", "acyclic_siblings"}
    layers = next(c for c in contracts if c["type"] == "layers")["layers"]
    assert layers[-2:] == ["aerotri.geom", "aerotri.core"]
    assert "|" in layers[-3]  # the stages: independent of each other


def test_lint_imports_keeps_every_contract():
    lint = Path(sys.executable).with_name("lint-imports")
    r = subprocess.run([str(lint), "--no-cache"], cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
