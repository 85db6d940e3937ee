"""Same products on every Dask scheduler (issue 41): the demo's whole chain (``aerotri demo``) run once on local
threads (the default) and once on a Dask LocalCluster of 2 worker processes (``--scheduler local:2``), every
file of the two projects compared.

    python bench/eval_scheduler_equality.py --run WORK      (runs both demos into WORK/threads and WORK/cluster)
    python bench/eval_scheduler_equality.py --compare WORK   (compares what is there)
        [--json bench/results/scheduler_equality.json]

On a full-size block the two chains are run by ``bench/scale.py`` (its stage table for each), then compared:

    python bench/scale.py --size dmc_2x2 --run-dir WORK/threads --key K_THREADS
    python bench/scale.py --size dmc_2x2 --run-dir WORK/cluster --scheduler local:2 --key K_CLUSTER
    python bench/eval_scheduler_equality.py --compare WORK --scale-json bench/results/scale_dmc.json \
        --json bench/results/scheduler_equality_dmc_2x2.json

``--scale-json`` takes each run's command, wall, CPU and peak memory from the entry of that file whose run folder
is WORK/threads or WORK/cluster.

Files are compared by SHA-256: text (JSON, CSV, TXT, GeoJSON, XML, HTML) with the run's folder name replaced,
the run-time columns of summary.txt's stage table left out; a GeoPackage by its SQL without the time each layer
was written; an .npz (the feature caches) by its arrays (the zip's member dates differ). A JSON file that still
differs is compared key by key: keys that are run times, load, peak memory, the scheduler or a file's mtime are
expected to differ, and so are a stage stamp's hashes of input files that differ only in such keys; any other key,
or any other file, is a difference in the products.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

TEXT_SUFFIXES = (".json", ".csv", ".txt", ".geojson", ".xml", ".html", ".toml", ".prj", ".log")
# keys of a run's records that say how it ran, not what it made
RUN_KEYS = re.compile(r"time|elapsed|wall|cpu|peak|rss|memory_mb|scheduler|workers|host|pid|started|finished|"
                      r"duration|seconds|_s$|date|version|load_avg|mtime|points_per_s|_utc$", re.I)
# a stage stamp's [size, mtime_ns] of a file too large to hash: its mtime is a run record
STAMP_MTIME = re.compile(r"/(inputs|outputs)/.+\[1\]$")
# when a page was made ("Made 2026-12-07T00:16:48Z")
ISO_TIME = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z")
# summary.txt's stage rows: "stage  status  time s  CPU s  peak MB  key numbers"
STAGE_ROW = re.compile(r"^(\S+\s+\S+)\s+[\d.]+\s+[\d.-]+\s+[\d-]+(.*)$", re.M)


def _digest(p: Path, root: Path) -> str:
    if p.suffix == ".gpkg":
        con = sqlite3.connect(f"file:{p}?mode=ro", uri=True)
        sql = "\n".join(con.iterdump())
        con.close()
        return hashlib.sha256(re.sub(r"'\d{4}-\d\d-\d\dT[0-9:.]+Z'", "'T'", sql).encode()).hexdigest()
    if p.suffix == ".npz":
        import numpy as np

        h = hashlib.sha256()
        with np.load(p, allow_pickle=False) as z:
            for k in sorted(z.files):
                a = z[k]
                if k == "meta":  # the feature cache's key: the image's size and mtime (a run record)
                    meta = {m: v for m, v in json.loads(str(a)).items() if not RUN_KEYS.search(m)}
                    a = np.array(json.dumps(meta, sort_keys=True))
                h.update(f"{k}{a.dtype}{a.shape}".encode())
                h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()
    data = p.read_bytes()
    if p.suffix in TEXT_SUFFIXES:
        text = ISO_TIME.sub("TIME", _neutral(data.decode("utf-8", "replace"), root))
        if p.suffix == ".html":  # a page's title and heading name the project by its folder
            text = re.sub(rf"(?<![\w/.-]){re.escape(root.name)}(?![\w/-])", "ROOT", text)
        if p.name == "summary.txt":
            text = STAGE_ROW.sub(r"\1\2", text)
        data = text.encode()
    return hashlib.sha256(data).hexdigest()


def _neutral(text: str, root: Path) -> str:
    """``text`` with the run's folder named ROOT (absolute, and relative as the summary prints it)."""
    return re.sub(rf"(?<![\w.-]){re.escape(root.name)}/", "ROOT/", text.replace(str(root), "ROOT"))


def _json_differences(a, b, path: str = "") -> list[str]:
    """Key paths where two JSON documents differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _json_differences(a.get(k), b.get(k), f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        out = []
        for i, (x, y) in enumerate(zip(a, b)):
            out += _json_differences(x, y, f"{path}[{i}]")
        return out
    return [] if a == b else [path or "/"]


def _neutral_json(p: Path, root: Path):
    return json.loads(_neutral(p.read_text(errors="replace"), root))


def compare(a_root: Path, b_root: Path) -> dict:
    files_a = {p.relative_to(a_root).as_posix(): p for p in a_root.rglob("*") if p.is_file()}
    files_b = {p.relative_to(b_root).as_posix(): p for p in b_root.rglob("*") if p.is_file()}
    names = sorted(set(files_a) | set(files_b))
    only = [n for n in names if (n in files_a) != (n in files_b)]
    identical, run_records, products_differ, pending = [], {}, {}, {}
    for n in names:
        if n in only:
            continue
        if _digest(files_a[n], a_root) == _digest(files_b[n], b_root):
            identical.append(n)
            continue
        if n.endswith(".json"):
            keys = _json_differences(_neutral_json(files_a[n], a_root), _neutral_json(files_b[n], b_root))
            product_keys = [k for k in keys if not any(RUN_KEYS.search(part) for part in k.split("/"))
                            and not STAMP_MTIME.search(k)]
            if not product_keys:
                run_records[n] = keys
            else:
                pending[n] = (keys, product_keys)
        else:
            products_differ[n] = ["bytes"]
    # a stage stamp's /inputs/<file> and /outputs/<file> (a hash of that file) and mosaic.json's index_sha1 (of
    # ortho/frames/index.json) follow files that differ in run records only
    changed = True
    while changed:
        changed = False
        for n, (keys, product_keys) in list(pending.items()):
            derived = {k: k.split("/inputs/", 1)[-1] if "/inputs/" in k else k.split("/outputs/", 1)[-1]
                       if "/outputs/" in k else "ortho/frames/index.json" if k.endswith("/index_sha1") else None
                       for k in product_keys}
            # (a file identical but for the folder name in it also changes the stamp's hash of its bytes)
            follows = [k for k, f in derived.items()
                       if f is not None and any(r.endswith(f) for r in [*run_records, *identical])]
            if len(follows) == len(product_keys):
                run_records[n] = keys
                del pending[n]
                changed = True
    products_differ.update({n: pk[:20] for n, (_, pk) in pending.items()})
    return {"files": len(names), "identical": len(identical), "only_in_one": only,
            "differ_in_run_records_only": run_records, "products_differ": products_differ}


def _run_demo(out: Path, scheduler: str | None) -> dict:
    # aerotri.cli has no __main__ (``-m aerotri.cli`` ran nothing): the console script's call
    cmd = [sys.executable, "-c", "import sys; from aerotri.cli import main; sys.exit(main())", "demo", str(out), "-q"]
    if scheduler:
        cmd += ["--scheduler", scheduler]
    t0 = time.time()
    r = subprocess.run(["/usr/bin/time", "-f", "%U %S %M", *cmd], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    user, sys_, rss = r.stderr.strip().splitlines()[-1].split()
    return {"command": " ".join(cmd[1:]), "wall_s": round(time.time() - t0, 1),
            "cpu_s": round(float(user) + float(sys_), 1), "peak_rss_mb": round(int(rss) / 1024, 1)}


def _runs_from_scale(path: Path, work: Path) -> tuple[dict, dict]:
    """The records of bench/scale.py's entries run in WORK/threads and WORK/cluster, and their commands."""
    entries = json.loads(path.read_text())
    runs, labels = {}, {}
    for name in ("threads", "cluster"):
        found = [(k, e) for k, e in entries.items()
                 if isinstance(e, dict) and Path(str(e.get("run_dir", ""))).resolve() == (work / name).resolve()]
        if not found:
            raise SystemExit(f"{path}: no entry whose run_dir is {work / name}")
        key, e = found[-1]
        run = e.get("run") or {}
        labels[name] = f"{run.get('command', '?')} ({path.name} key {key})"
        runs[name] = {"key": key, "wall_s": run.get("wall_s"), "cpu_s": run.get("cpu_s"),
                      "largest_process_peak_rss_mb": run.get("largest_process_peak_rss_mb"),
                      "stages_wall_min": (e.get("verdict") or {}).get("stages_wall_min"),
                      "cpu_min": (e.get("verdict") or {}).get("cpu_min"), "measured_utc": e.get("measured_utc")}
    return runs, labels


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--run", type=Path, help="run both demos into this folder, then compare")
    g.add_argument("--compare", type=Path, help="compare WORK/threads and WORK/cluster")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--scale-json", type=Path,
                    help="bench/scale.py's results file: the two runs' records from its entries for WORK/threads and "
                         "WORK/cluster (chains run by bench/scale.py)")
    a = ap.parse_args()
    work = a.run or a.compare
    runs = {}
    if a.run:
        runs = {"threads": _run_demo(work / "threads", None), "cluster": _run_demo(work / "cluster", "local:2")}
    else:  # runs made by hand under `/usr/bin/time -v ... > WORK/<name>.log`
        for name in ("threads", "cluster"):
            log = work / f"{name}.log"
            if log.exists():
                t = dict(re.findall(r"^\t([^:]+(?:\([^)]*\))?[^:]*): (.+)$", log.read_text(), re.M))
                runs[name] = {"cpu_s": round(float(t["User time (seconds)"]) + float(t["System time (seconds)"]), 1),
                              "peak_rss_mb": round(int(t["Maximum resident set size (kbytes)"]) / 1024, 1),
                              "wall": t["Elapsed (wall clock) time (h:mm:ss or m:ss)"]}
    labels = {"threads": "aerotri demo (Dask local threads, 2)", "cluster": "aerotri demo --scheduler local:2"}
    if a.scale_json:
        runs, labels = _runs_from_scale(a.scale_json, work)
    result = {**labels, "runs": runs, **compare(work / "threads", work / "cluster")}
    n_prod = len(result["products_differ"]) + len(result["only_in_one"])
    print(f"{result['files']} files: {result['identical']} identical, "
          f"{len(result['differ_in_run_records_only'])} differ in run records only (times, memory, scheduler), "
          f"{n_prod} differ in products" + (": " + ", ".join([*result["products_differ"], *result["only_in_one"]])
                                             if n_prod else ""))
    if a.json:
        a.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
