"""The wheel works without the source tree: it carries the presets, tolerance tables, page templates and licence, declares
one version and every imported third-party package, and ``aerotri sim --preset tiny`` runs from it."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(build_once) -> Path:
    # built once per run: pip builds in the source tree (build/, *.egg-info), which two xdist workers must not share
    out = build_once("wheel", lambda out: subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                                                          str(out), str(REPO)], check=True, capture_output=True))
    (whl,) = out.glob("aerotri-*.whl")
    return whl


def test_wheel_file_list(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for preset in ("tiny", "demo", "dmc"):
        assert any(n.endswith(f"data/share/aerotri/presets/{preset}.toml") for n in names), preset
    for scale in ("1to2000", "1to5000", "1to10000"):
        assert f"aerotri/core/tolerance_tables/cn_{scale}.toml" in names
    for std in ("asprs2023", "usgs_lbs", "cn_at"):  # the standards of the compliance section
        assert f"aerotri/qa/standards/{std}.toml" in names
    for page in ("aerotri/templates/macros.html.j2", "aerotri/templates/adjust_report.html.j2",
                 "aerotri/templates/qa_report.html.j2", "aerotri/templates/control_review.html.j2",
                 "aerotri/templates/report.css", "lidarctl/templates/strips_check.html.j2"):  # aerotri.core.pages
        assert page in names, page
    assert any(n.endswith("dist-info/licenses/LICENSE") for n in names)
    for pkg in ("aerotri/core/errors.py", "aerotri/geom/crs/transform.py", "lidarctl/cli/main.py", "ortho/cli.py"):
        assert pkg in names
    assert not any(n.startswith(("tests/", "bench/", "datasets/")) for n in names)
    meta = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("dist-info/METADATA"))).decode()
    assert "License-Expression: BSD-3-Clause" in meta
    import aerotri

    assert f"Version: {aerotri.__version__}" in meta


def test_every_imported_package_is_declared(wheel):
    """Third-party imports of the three packages against the wheel's Requires-Dist."""
    meta = zipfile.ZipFile(wheel).read(next(n for n in zipfile.ZipFile(wheel).namelist()
                                            if n.endswith("dist-info/METADATA"))).decode()
    import re

    declared = set()
    for ln in meta.splitlines():
        if ln.startswith("Requires-Dist:") and "extra ==" not in ln:
            m = re.match(r"\s*([A-Za-z0-9_.-]+)(\[([^\]]*)\])?", ln.split(":", 1)[1])
            declared.add(m.group(1).lower())
            declared |= {e.strip().lower() for e in (m.group(3) or "").split(",") if e.strip()}  # laspy[lazrs]
    module_to_dist = {"cv2": "opencv-contrib-python-headless", "PIL": "pillow", "yaml": "pyyaml", "sklearn": None,
                      "distributed": "dask", "osgeo": None}
    stdlib = set(sys.stdlib_module_names)
    ours = {"aerotri", "lidarctl", "ortho"}
    missing = set()
    for pkg in ours:
        for f in (REPO / pkg).rglob("*.py"):
            for node in ast.walk(ast.parse(f.read_text())):
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                    [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else [])
                for m in mods:
                    top = m.split(".")[0]
                    if top in stdlib or top in ours:
                        continue
                    dist = module_to_dist.get(top, top).lower() if module_to_dist.get(top, top) else None
                    if dist and dist.replace("_", "-") not in {d.replace("_", "-") for d in declared}:
                        missing.add(f"{top} ({f.relative_to(REPO)})")
    assert not missing, sorted(missing)


def _numba_caches_of_the_tree(site: Path) -> int:
    """Copy the source tree's numba caches (``__pycache__/*.nbi, *.nbc``) next to the installed modules whose
    source is byte-identical, with the tree's modification time (the source stamp numba checks), so the installed
    wheel loads the kernels the tree compiled (on a clean clone ``tiny_project`` compiled the simulator's) instead
    of compiling them again: 57 of 61 CPU-s of the tiny run (docs/testing.md). Numba loads a kernel only when the
    hash of its bytecode matches, so what runs is the installed wheel's code. Returns the number of modules."""
    n = 0
    for index in sorted(p for pkg in ("aerotri", "lidarctl", "ortho") for p in (REPO / pkg).rglob("__pycache__/*.nbi")):
        rel = index.parent.parent.relative_to(REPO) / (index.name.split(".")[0] + ".py")
        src, installed = REPO / rel, site / rel
        if not installed.is_file() or installed.read_bytes() != src.read_bytes():
            continue
        st = src.stat()
        os.utime(installed, ns=(st.st_atime_ns, st.st_mtime_ns))
        (installed.parent / "__pycache__").mkdir(exist_ok=True)
        for f in index.parent.glob(index.name[:-len(".nbi")] + ".*"):  # the index and its .nbc data files
            shutil.copy2(f, installed.parent / "__pycache__" / f.name)
        n += 1
    return n


def test_installed_wheel_simulates_tiny(wheel, tiny_project, tmp_path):
    prefix = tmp_path / "prefix"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--ignore-installed", "--no-compile", "-q",
                    "--prefix", str(prefix), str(wheel)], check=True, capture_output=True)
    (site,) = prefix.glob("lib/python*/site-packages")
    _numba_caches_of_the_tree(site)
    env = dict(os.environ, PYTHONPATH=str(site))
    env.pop("AEROTRI_PRESETS", None)
    code = ("import aerotri, sys; from aerotri.cli import main; assert aerotri.__file__.startswith(sys.argv[1]), "
            "aerotri.__file__; sys.argv = ['aerotri', 'sim', '--preset', 'tiny', '-q', sys.argv[2]]; main()")
    out = tmp_path / "tiny"
    r = subprocess.run([sys.executable, "-c", code, str(site), str(out)], cwd=tmp_path, env=env, capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (out / "project.toml").is_file() and len(list((out / "images").glob("*"))) == 6


def test_constraints_pin_every_declared_dependency_inside_its_range():
    """``constraints.txt`` (what ``make install`` installs, pip's -c) pins one version of every dependency of
    pyproject.toml and its ``test`` extra, each inside the range pyproject declares: a dependency added to pyproject
    without its tested version, or a range moved past the pin, fails here rather than on a fresh clone."""
    import tomllib

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name
    from packaging.version import Version

    pins = {}
    for n, line in enumerate((REPO / "constraints.txt").read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, version = line.partition("==")
        assert sep and version, f"constraints.txt line {n}: {line!r} is no name==version pin"
        pins[canonicalize_name(name)] = Version(version)
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    for spec in project["dependencies"] + project["optional-dependencies"]["test"]:
        req = Requirement(spec)
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is declared in pyproject.toml but not pinned in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), f"{req.name}=={pins[name]} outside {req.specifier}"
        for extra in req.extras:  # laspy[lazrs]
            assert canonicalize_name(extra) in pins, f"{req.name}[{extra}]: {extra} not pinned in constraints.txt"
