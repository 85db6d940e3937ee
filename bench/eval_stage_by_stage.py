"""The README's stage-by-stage commands against ``aerotri run`` on the demo project (issue 39, item 9).

Two copies of the demo project (``aerotri demo``'s simulated block; default the reference run
/work/ref/demo_chain/project): the block's inputs alone (camera.toml, gnss.txt, images/, lidar/, project.toml,
trajectory/, truth/) run the commands of the README's stage-by-stage block ("The chain (what `aerotri run` and
`make demo` do)"), read from README.md, one by one as a user types them (P the copy, REF.tif the true
orthophoto, POINTS.csv the surveyed targets, lines of the block only); the other runs ``aerotri run P
--reference P/truth/ortho.tif`` (the chain) with the demo run's LiDAR stages (strip check, classification,
rasters, corners: their products and stamps; ``--chain-from``) and every stage from the tie points on
again. The LiDAR products of both are compared file by file (``lidar_products_identical``). Both are
measured the same way against the simulator's truth (``truth/`` is read by the measurement alone):

- AT check against the surveyed targets: ``bench/eval_variants.py``'s ``target_check`` (each target seen by
  two or more frames intersected with the final orientations and self-calibrated camera, RMS plan / height);
- the final adjustment report's own check (``at/report.json`` check_rms_m: LiDAR corners not used as control);
- attitudes: RMS of omega, phi, kappa of ``at/eo.txt`` against ``truth/eo.txt``;
- DOM: ``ortho/dom_report.json`` displacement RMS against the true orthophoto (the chain's ``dom_check``
  stage, the block's ``ortho check``);
- the settings each final adjustment used, with their sources (``at/report.json`` settings): the values must
  be the same, the sources say which came from project.toml and which from the command line.

Writes ``bench/results/stage_by_stage_demo.json``.

    .venv/bin/python bench/eval_stage_by_stage.py [--demo /work/ref/demo_chain/project] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from eval_variants import code_version, corner_check, target_check  # noqa: E402


def readme_commands(readme: Path = REPO / "README.md") -> list[str]:
    """The command lines of the README's stage-by-stage block (the first code block after its heading),
    comments removed."""
    text = readme.read_text()
    at = text.index("### The chain (what `aerotri run` and `make demo` do)")
    block = re.search(r"```\n(.*?)```", text[at:], re.S).group(1)
    return [line.split("  #")[0].strip() for line in block.splitlines() if line.strip()]


def _run(cmd: str, log, cwd: Path) -> float:
    t0 = time.perf_counter()
    log.write(f"$ {cmd}\n")
    log.flush()
    subprocess.run(cmd, shell=True, check=True, stdout=log, stderr=subprocess.STDOUT, cwd=cwd,
                   executable="/bin/bash")
    return time.perf_counter() - t0


INPUTS = ("README.txt", "camera.toml", "gnss.txt", "images", "lidar", "project.toml", "trajectory", "truth")
LIDAR_STAGES = ("strips", "classify", "rasters", "corners")
LIDAR_PRODUCTS = ("dem.tif", "dsm.tif", "ndsm.tif", "corners.csv", "roof_planes.geojson")
DEMO_PRODUCTS = ("at/tiepoints.csv", "work/at_first/eo.txt", "work/at_first/camera.toml", "control/points.csv",
                 "control/image_points.csv", "at/eo.txt", "at/object_points.csv", "ortho/mosaic.tif")


def _inputs_copy(src: Path, dst: Path) -> Path:
    """The demo project's inputs alone (no product of any stage)."""
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in INPUTS:
        if (src / name).is_dir():
            shutil.copytree(src / name, dst / name, symlinks=True)
        elif (src / name).is_file():
            shutil.copy2(src / name, dst / name)
    return dst


def _chain_copy(src: Path, dst: Path) -> Path:
    """The inputs with the demo run's LiDAR stages (products in lidar_out/ and their stamps): the chain runs every
    stage from the tie points on."""
    _inputs_copy(src, dst)
    shutil.copytree(src / "lidar_out", dst / "lidar_out", symlinks=True)
    (dst / "work" / "stages").mkdir(parents=True)
    for stage in LIDAR_STAGES:
        shutil.copy2(src / "work" / "stages" / f"{stage}.json", dst / "work" / "stages" / f"{stage}.json")
    for extra in ("classification_eval.json", "height_check.json"):  # made by checks the chain does not run here
        (dst / "lidar_out" / extra).unlink(missing_ok=True)
    return dst


def _same_bytes(a: Path, b: Path) -> bool:
    return a.is_file() and b.is_file() and a.read_bytes() == b.read_bytes()


def attitude_rms(root: Path) -> dict:
    """RMS (deg) of omega, phi, kappa of at/eo.txt against truth/eo.txt, over the frames of both."""
    from aerotri.geom.eo import read_eo

    got, true = read_eo(root / "at" / "eo.txt"), read_eo(root / "truth" / "eo.txt")
    sel = true.rows(got.image_id)
    d = (got.opk_deg - true.opk_deg[sel] + 180.0) % 360.0 - 180.0
    rms = np.sqrt(np.mean(d ** 2, axis=0))
    return dict(n=len(sel), omega_deg=float(rms[0]), phi_deg=float(rms[1]), kappa_deg=float(rms[2]))


def measure(root: Path) -> dict:
    truth = json.loads((root / "truth" / "truth.json").read_text())
    gsd = float(truth["gsd_m"])
    at = json.loads((root / "at" / "report.json").read_text())
    dom = json.loads((root / "ortho" / "dom_report.json").read_text())
    d = dom.get("displacement", {})
    return dict(
        at_check_targets=target_check(root), report_check_rms_m=at.get("check_rms_m"),
        lidar_corner_check=corner_check(root, gsd), attitudes=attitude_rms(root),
        sigma0_px=at["key_statistics"].get("sigma0_px"), verdict=at["key_statistics"].get("message"),
        options=at["options"], dom=dict(n=d.get("count"), rms_xy_m=d.get("rms_xy_m"), ndsm=dom.get("ndsm")),
        adjust_settings=at.get("settings"), gsd_m=gsd)


def differences(a: dict, b: dict, root_a: Path, root_b: Path) -> dict:
    """Settings whose values differ between two settings records (path -> [a, b]); file names relative to each
    project folder (the two copies lie in different folders)."""
    def value(rec, k, root):
        v = rec.get(k, {}).get("value")
        return v.replace(str(root), "P") if isinstance(v, str) else v

    return {k: [value(a, k, root_a), value(b, k, root_b)] for k in sorted(set(a) | set(b))
            if value(a, k, root_a) != value(b, k, root_b)}


def old_code_run(a, commands: list[str], by_hand: Path, old: Path) -> dict:
    """The block's aerotri and ortho commands (the lidarctl ones' products taken from ``by_hand``) run with the code
    of ``a.old_code`` (PYTHONPATH), measured as the others; None-valued settings: that code records none."""
    bin_ = Path(sys.executable).parent
    if not (a.keep and (old / "ortho" / "dom_report.json").is_file()):
        _inputs_copy(a.demo, old)
        shutil.copytree(by_hand / "lidar_out", old / "lidar_out", symlinks=True)
        env = f"PYTHONPATH={a.old_code}"
        with open(a.work / "by_hand_old_code.log", "w") as log:
            for cmd in commands:
                if not cmd.startswith(("aerotri", "ortho")):
                    continue
                line = cmd.replace("REF.tif", f"{old}/truth/ortho.tif")
                line = re.sub(r"(?<![\w/])P(?=/|\s|$)", str(old), line)
                words = shlex.split(line)
                words[0] = str(bin_ / words[0])
                _run(f"{env} " + " ".join(words), log, REPO)
    m = measure(old)
    m["code"] = str(a.old_code)
    return m


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--demo", type=Path, default=Path("/work/ref/demo_chain/project"))
    ap.add_argument("--work", type=Path, default=Path("/work/tmp/stage_by_stage"))
    ap.add_argument("--results", type=Path, default=REPO / "bench" / "results" / "stage_by_stage_demo.json")
    ap.add_argument("--keep", action="store_true", help="measure the copies of an earlier run without running")
    ap.add_argument("--parallel", action="store_true", help="run the chain while the commands run (two processes)")
    ap.add_argument("--old-code", type=Path, default=None,
                    help="a copy of the code before this change (git archive): the block's aerotri and ortho commands "
                         "run with it on a copy with the LiDAR products of the commands run here (by_hand_old_code)")
    a = ap.parse_args()
    bin_ = Path(sys.executable).parent
    chain, by_hand = a.work / "chain" / "project", a.work / "by_hand" / "project"
    commands = readme_commands()
    timing = {}
    if a.keep and a.results.is_file():  # the timings of the run that made the copies
        timing = json.loads(a.results.read_text()).get("timing", {})
        if timing.get("parallel") and "chain_s" in timing:  # written by a version that timed both as the chain's
            timing["both_s"] = timing.pop("chain_s")
    if not a.keep:
        _chain_copy(a.demo, chain)
        _inputs_copy(a.demo, by_hand)
        chain_cmd = f"{bin_}/aerotri run {chain} --reference {chain}/truth/ortho.tif"
        chain_log = open(a.work / "chain.log", "w")
        t_chain = time.perf_counter()
        if a.parallel:
            chain_log.write(f"$ {chain_cmd}\n")
            chain_log.flush()
            running = subprocess.Popen(chain_cmd, shell=True, stdout=chain_log, stderr=subprocess.STDOUT, cwd=REPO,
                                       executable="/bin/bash")
        else:
            timing["chain_s"] = round(_run(chain_cmd, chain_log, REPO), 1)
        steps = []
        with open(a.work / "by_hand.log", "w") as log:
            for cmd in commands:
                line = (cmd.replace("REF.tif", f"{by_hand}/truth/ortho.tif")
                        .replace("POINTS.csv", f"{by_hand}/truth/checkpoints.csv"))
                line = re.sub(r"(?<![\w/])P(?=/|\s|$)", str(by_hand), line)
                words = shlex.split(line)
                words[0] = str(bin_ / words[0])
                steps.append(dict(command=cmd, seconds=round(_run(" ".join(words), log, REPO), 1)))
        timing["by_hand_steps"] = steps
        timing["by_hand_s"] = round(sum(s["seconds"] for s in steps), 1)
        if a.parallel:
            if running.wait() != 0:
                raise SystemExit(f"aerotri run failed: {a.work / 'chain.log'}")
            timing["both_s"] = round(time.perf_counter() - t_chain, 1)
        chain_log.close()
        timing["parallel"] = a.parallel
        timing["load_avg_end"] = list(os.getloadavg())
    # a run from a snapshot of the code (git archive, PYTHONPATH) names its commit in AEROTRI_CODE_VERSION
    out = dict(code=os.environ.get("AEROTRI_CODE_VERSION") or code_version(), demo=str(a.demo),
               readme_commands=commands, timing=timing, chain=measure(chain), by_hand=measure(by_hand))
    # the chain's own wall time, stage by stage (work/run_summary.json), also when it ran beside the commands
    rows = json.loads((chain / "work" / "run_summary.json").read_text())["stages"]
    out["timing"]["chain_stages_s"] = round(sum(r["seconds"] for r in rows), 1)
    out["settings_differ"] = differences(out["chain"]["adjust_settings"], out["by_hand"]["adjust_settings"], chain,
                                         by_hand)
    same_eo = (chain / "at" / "eo.txt").read_bytes() == (by_hand / "at" / "eo.txt").read_bytes()
    out["same_at_eo_txt"] = same_eo
    out["lidar_products_identical"] = {f: _same_bytes(chain / "lidar_out" / f, by_hand / "lidar_out" / f)
                                       for f in LIDAR_PRODUCTS}
    # the chain against the demo run it started from (made by the code the demo was run with): the same products
    out["chain_products_as_in_demo"] = {f: _same_bytes(chain / f, a.demo / f) for f in DEMO_PRODUCTS
                                        if (a.demo / f).is_file()}
    if a.old_code is not None:
        out["by_hand_old_code"] = old_code_run(a, commands, by_hand, a.work / "by_hand_old_code" / "project")
    a.results.parent.mkdir(parents=True, exist_ok=True)
    a.results.write_text(json.dumps(out, indent=1) + "\n")
    for name in ("chain", "by_hand"):
        m = out[name]
        t, att = m["at_check_targets"], m["attitudes"]
        print(f"{name:8} targets plan {t['rms_xy_m']:.3f} m height {t['rms_z_m']:.3f} m (n {t['n']}); report check "
              f"{m['report_check_rms_m']}; attitudes {att['omega_deg']:.4f} {att['phi_deg']:.4f} "
              f"{att['kappa_deg']:.4f} deg; DOM {m['dom']['rms_xy_m']} m")
    print(f"settings that differ: {out['settings_differ'] or 'none'}; at/eo.txt identical: {same_eo}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
