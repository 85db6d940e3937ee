"""The production run: every stage over one project folder, resumable, with a summary at the end.

A stage is skipped when its stamp (``work/stages/<stage>.json``) records the same input files (content
hash; size and modification time for files over 64 MiB) and options as now and all its outputs exist; otherwise it runs and writes
its outputs atomically, then its stamp. Killing a run leaves finished stages stamped and the
interrupted stage without a stamp and without partial outputs, so a re-run continues there.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path

from aerotri.core.atomic import remove_leftovers, write_text_atomic


@dataclasses.dataclass
class Stage:
    name: str
    inputs: Callable[[Path], list[Path]]  # files whose change re-runs the stage
    outputs: Callable[[Path], list[Path]]  # files the stage must leave behind
    run: Callable[[Path], dict]  # does the work, returns key numbers for the summary
    options: dict = dataclasses.field(default_factory=dict)


def _signature(paths: list[Path], hash_limit_bytes: int = 64 << 20) -> dict:
    """Content hash of each input up to ``hash_limit_bytes`` (timestamps are too coarse to trust),
    size and modification time beyond that."""
    sig = {}
    for p in sorted(paths, key=str):
        if p.is_file():
            st = p.stat()
            if st.st_size <= hash_limit_bytes:
                sig[str(p)] = hashlib.sha1(p.read_bytes()).hexdigest()
            else:
                sig[str(p)] = [st.st_size, st.st_mtime_ns]
        else:
            sig[str(p)] = None
    return sig


def stamp_path(root: Path, stage: str) -> Path:
    return root / "work" / "stages" / f"{stage}.json"


def is_current(root: Path, st: Stage) -> bool:
    sp = stamp_path(root, st.name)
    if not sp.exists():
        return False
    try:
        stamp = json.loads(sp.read_text())
    except json.JSONDecodeError:
        return False
    if not all(p.exists() for p in st.outputs(root)):
        return False
    return stamp.get("inputs") == _signature(st.inputs(root)) and stamp.get("options") == st.options


def run_stages(root, stages: list[Stage], force: bool = False, log=print) -> list[dict]:
    """Run (or skip) the stages in order; returns one summary row per stage."""
    root = Path(root)
    rows = []
    for st in stages:
        if not force and is_current(root, st):
            stamp = json.loads(stamp_path(root, st.name).read_text())
            rows.append(dict(stage=st.name, status="skipped (up to date)", seconds=0.0, **stamp.get("result", {})))
            log(f"[{st.name}] up to date, skipped")
            continue
        log(f"[{st.name}] running")
        _remove_stale_temporaries(st.outputs(root))
        t = time.perf_counter()
        result = st.run(root) or {}
        dt = time.perf_counter() - t
        missing = [str(p) for p in st.outputs(root) if not p.exists()]
        if missing:
            raise RuntimeError(f"stage {st.name} finished without writing {', '.join(missing)}")
        write_text_atomic(stamp_path(root, st.name), json.dumps(
            dict(inputs=_signature(st.inputs(root)), options=st.options, result=result, seconds=round(dt, 2)),
            indent=1, default=str) + "\n")
        rows.append(dict(stage=st.name, status="done", seconds=round(dt, 1), **result))
        log(f"[{st.name}] done in {dt:.1f} s")
    return rows


def _remove_stale_temporaries(outputs: list[Path]) -> None:
    """Delete what a killed earlier attempt left of its atomic writes in the folders of the stage's
    outputs (``aerotri.core.atomic.remove_leftovers``: the frame files next to ortho/frames/index.json, the
    mosaic's and the rasters' work folders, the LiDAR tiles' work folder, ...)."""
    for folder in sorted({p.parent for p in outputs}):
        remove_leftovers(folder)


def format_summary(rows: list[dict]) -> str:
    lines = [f"{'stage':<18} {'status':<22} {'time s':>7}  key numbers"]
    for r in rows:
        extra = "  ".join(f"{k}={_fmt(v)}" for k, v in r.items() if k not in ("stage", "status", "seconds"))
        lines.append(f"{r['stage']:<18} {r['status']:<22} {r['seconds']:>7.1f}  {extra}")
    return "\n".join(lines)


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


# ----------------------------------------------------------------------------------------------
# The chain of stages over one project folder


def _invoke(group, args: list) -> None:
    """Run a click command in-process; a failing command (its message already printed) stops the run."""
    from aerotri.core.errors import InputError

    try:
        group.main(args=[str(a) for a in args], standalone_mode=False)
    except SystemExit as exc:
        if exc.code:
            raise InputError(f"stage command failed: {' '.join(str(a) for a in args)}") from None


def _lidar_inputs(root: Path) -> list[Path]:
    return sorted(p for p in (root / "lidar").glob("*") if p.suffix.lower() in (".las", ".laz"))


def _json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}


def chain_stages(root: Path, raster_res_m: float = 0.5, reference_ortho: Path | None = None,
                 surveyed_points: Path | None = None, truth_classes: bool = False) -> list[Stage]:
    """The production chain: LiDAR -> control candidates -> tie points -> adjustments -> ortho -> checks.

    ``reference_ortho`` and ``surveyed_points`` switch on the DOM and LiDAR height checks;
    ``truth_classes`` (simulated projects) evaluates the classification against truth/lidar.
    """
    from aerotri.cli import main as aerotri_cli
    from lidarctl.cli import main as lidarctl_cli
    from ortho.cli import main as ortho_cli

    merged = root / "work" / "lidar" / "merged.las"
    classified = root / "lidar_out" / "classified.laz"
    lo = root / "lidar_out"
    first = root / "work" / "at_first"

    def merge(r):
        from lidarctl.merge import merge_las

        return dict(points=merge_las(_lidar_inputs(r), merged))

    def classify(r):
        _invoke(lidarctl_cli, ["classify", merged, classified])
        return {}

    def rasters(r):
        _invoke(lidarctl_cli, ["rasters", classified, lo, "--res", raster_res_m])
        return {}

    def corners(r):
        _invoke(lidarctl_cli, ["corners", classified, lo])
        s = _json(lo / "corners.json")
        return {k: s[k] for k in ("corners", "usable") if k in s}

    def match(r):
        _invoke(aerotri_cli, ["match", r])
        c = _json(r / "at" / "connectivity.json")
        return dict(tracks=c.get("tracks"), observations=c.get("observations"), components=c.get("components"))

    def adjust_first(r):
        _invoke(aerotri_cli, ["adjust", r, "--self-cal", "pp,radial", "--no-control", "--no-html"])
        from aerotri.camera import FrameCamera
        from aerotri.core.atomic import write_text_atomic as wta

        first.mkdir(parents=True, exist_ok=True)
        rep = _json(r / "at" / "report.json")
        cam = rep.get("self_calibration", {}).get("camera")
        wta(first / "camera.toml", (FrameCamera.from_dict(cam) if cam else FrameCamera.read(r / "camera.toml")).to_toml())
        wta(first / "eo.txt", (r / "at" / "eo.txt").read_text())
        wta(first / "report.json", (r / "at" / "report.json").read_text())
        return _adjust_numbers(rep)

    def control(r):
        _invoke(aerotri_cli, ["control", r, "--eo", first / "eo.txt", "--camera", first / "camera.toml"])
        t = _json(r / "control" / "transfer.json").get("summary", {})
        return {k: t[k] for k in ("corners_accepted", "control_full", "control_height", "check_points") if k in t}

    def adjust_final(r):
        _invoke(aerotri_cli, ["adjust", r, "--gnss-correction", "shift", "--self-cal", "pp,radial"])
        return _adjust_numbers(_json(r / "at" / "report.json"))

    def rectify(r):
        _invoke(ortho_cli, ["rectify", r, "--dem", lo / "dem.tif"])
        return {}

    def mosaic(r):
        _invoke(ortho_cli, ["mosaic", r])
        return {}

    stages = [
        Stage("merge", _lidar_inputs, lambda r: [merged], merge),
        Stage("classify", lambda r: [merged], lambda r: [classified], classify),
        Stage("rasters", lambda r: [classified], lambda r: [lo / f for f in ("dem.tif", "dsm.tif", "ndsm.tif")], rasters,
              dict(res_m=raster_res_m)),
        Stage("corners", lambda r: [classified], lambda r: [lo / "corners.csv"], corners),
        Stage("match", lambda r: sorted((r / "images").glob("*")) + [r / "gnss.txt", r / "camera.toml"],
              lambda r: [r / "at" / "tiepoints.csv"], match),
        # project.toml carries the [gnss]/[control] sigmas, [adjust] image sigma and the [qa] limits of the report
        Stage("adjust_first", lambda r: [r / "at" / "tiepoints.csv", r / "gnss.txt", r / "camera.toml", r / "project.toml"],
              lambda r: [first / "eo.txt", first / "camera.toml"], adjust_first),
        Stage("control", lambda r: [lo / "corners.csv", first / "eo.txt", first / "camera.toml"],
              lambda r: [r / "control" / "points.csv", r / "control" / "image_points.csv"], control),
        Stage("adjust_final", lambda r: [r / "at" / "tiepoints.csv", r / "control" / "points.csv",
                                         r / "control" / "image_points.csv", r / "gnss.txt", r / "camera.toml",
                                         r / "project.toml"],
              lambda r: [r / "at" / "eo.txt", r / "at" / "report.json"], adjust_final),
        # (the self-calibrated camera in at/report.json changes only with at/eo.txt)
        Stage("rectify", lambda r: [r / "at" / "eo.txt", lo / "dem.tif"] + sorted((r / "images").glob("*")),
              lambda r: [r / "ortho" / "frames" / "index.json"], rectify),
        Stage("mosaic", lambda r: [r / "ortho" / "frames" / "index.json"], lambda r: [r / "ortho" / "mosaic.tif"], mosaic),
    ]
    if reference_ortho is not None:
        def dom_check(r):
            _invoke(ortho_cli, ["check", r, "--reference", reference_ortho, "--ndsm", lo / "ndsm.tif"])
            d = _json(r / "ortho" / "dom_report.json").get("displacement", {})
            return {k: d[k] for k in ("rms_xy_m", "rms_xy_gsd", "count") if k in d}

        stages.append(Stage("dom_check", lambda r: [r / "ortho" / "mosaic.tif", reference_ortho],
                            lambda r: [r / "ortho" / "dom_report.json"], dom_check))
    if surveyed_points is not None:
        def height_check(r):
            _invoke(lidarctl_cli, ["check-heights", classified, surveyed_points, "--json", lo / "height_check.json"])
            a = _json(lo / "height_check.json").get("overall", {}).get("all", {})
            return {k: a[k] for k in ("rmse_m", "mean_abs_dz_m", "n") if k in a}

        stages.append(Stage("height_check", lambda r: [classified, surveyed_points],
                            lambda r: [lo / "height_check.json"], height_check))
    if truth_classes:
        truth_merged = root / "work" / "lidar" / "truth_merged.las"

        def lidar_eval(r):
            from lidarctl.merge import merge_las

            merge_las(sorted((r / "truth" / "lidar").glob("*.la[sz]")), truth_merged)
            _invoke(lidarctl_cli, ["evaluate", classified, "--truth", truth_merged, "--json",
                                   lo / "classification_eval.json"])
            g = _json(lo / "classification_eval.json").get("filter_test", {})
            return {k: g[k] for k in ("type_i_error_pct", "type_ii_error_pct", "kappa_pct") if k in g}

        stages.append(Stage("lidar_eval", lambda r: [classified], lambda r: [lo / "classification_eval.json"],
                            lidar_eval))
    def report(r):
        from aerotri.qa_report import write_qa_report

        rep = write_qa_report(r)
        return dict(verdict=rep["overall"], passed=rep["passed"], failed=rep["failed"])

    report_inputs = [root / "project.toml", root / "at" / "report.json", root / "control" / "transfer.json",
                     root / "ortho" / "dom_report.json", lo / "height_check.json", lo / "classification_eval.json"]
    stages.append(Stage("report", lambda r: report_inputs, lambda r: [r / "reports" / "index.html"], report))
    return stages


def _adjust_numbers(rep: dict) -> dict:
    out = {}
    ks = rep.get("key_statistics", {})
    if "sigma0_um" in ks:
        out["sigma0_um"] = ks["sigma0_um"]
    chk = rep.get("check_rms_m")
    if chk and len(chk) == 3 and None not in chk:
        out["rms_check_xy_m"] = round(float((chk[0] ** 2 + chk[1] ** 2) ** 0.5), 4)
        out["rms_check_z_m"] = chk[2]
    return out
