"""Bridge decks (class 17) on the data the rule was not chosen on, and on the demo it was (issue 44, i44-bridge)
-> bench/results/bridge_decks.json.

Per set, classified whole by ``classify_points`` (default settings): bridge-deck returns and their true classes,
deck PA / UA where a deck reference exists, and ground (2) and water (9) PA / UA against the set's reference.
Sets: the demo's four simulated strips (``--demo PROJECT``; truth/lidar; the simulator makes no bridges, so every
deck return is false: the rule was chosen here) and other simulated projects (``--sim DIR``, repeatable: the tiny
preset at seeds 7-9, the demo preset at seed 11); AHN3 Delft (its civil structures, class 26, are the canal
bridges' decks); Autzen (no reference classes for decks: the footbridge's corridor, ``eval_false_classes``);
the synthetic bridge scenes of tests/lidarctl/test_classify_bridge.py at seeds other than the tests'.

"Before" rows run main's code: export it and put it first on the path,
  git archive f930f728 lidarctl aerotri ortho | tar -x -C /tmp/main_src   (the base: main with i44-water)
  AEROTRI_SHARED_DATA=/work/shared/data PYTHONPATH=/tmp/main_src nice .venv/bin/python bench/eval_bridge_decks.py \
      --label main --demo /work/demo7/out/demo/project --sim /work/tmp/i44b/simtiny7 ...
(each label's rows are replaced, the other's kept); ``--others``: the remaining real sets only (ISPRS's 7 samples, lidR
Topography and MixedConifer, laspy Nebraska: deck returns and the classes' SHA-256).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import laspy
import numpy as np

from lidarctl import io
from lidarctl.classify import pipeline as classify

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "lidarctl"))
sys.path.insert(0, str(ROOT / "bench"))
DATA = Path(os.environ.get("AEROTRI_SHARED_DATA", "/work/shared/data"))
OUT = ROOT / "bench" / "results" / "bridge_decks.json"


def pa_ua(pred: np.ndarray, ref: np.ndarray) -> dict:
    both = int(np.sum(pred & ref))
    return {"truth": int(ref.sum()), "called": int(pred.sum()), "found": both,
            "pa_pct": round(100.0 * both / max(int(ref.sum()), 1), 2),
            "ua_pct": round(100.0 * both / max(int(pred.sum()), 1), 2)}


def score(cls, truth, deck_ref=None, seconds=0.0) -> dict:
    deck = cls == classify.BRIDGE_DECK
    out = {"seconds": round(seconds, 1), "bridge_deck": int(deck.sum()),
           "deck_truth_class": {str(k): int(v) for k, v in zip(*np.unique(truth[deck], return_counts=True))}}
    if deck_ref is not None:
        out["deck"] = pa_ua(deck, deck_ref)
    out["ground"] = pa_ua(cls == 2, truth == 2)
    out["water"] = pa_ua(cls == 9, truth == 9)
    return out


def real(path, crs=None) -> tuple:
    c = io.read_cloud(path, crs=crs)
    t = time.perf_counter()
    cls = classify.classify_points(c.x, c.y, c.z, c.return_number, c.number_of_returns, c.intensity)
    return c, cls, time.perf_counter() - t


def demo(project: Path) -> dict:
    strips = sorted((project / "lidar").glob("*.las"))
    las = [laspy.read(f) for f in strips]
    truth = np.concatenate([np.asarray(laspy.read(f).classification)
                            for f in sorted((project / "truth" / "lidar").glob("*.las"))])
    a = {k: np.concatenate([np.asarray(getattr(s, k)) for s in las])
         for k in ("x", "y", "z", "return_number", "number_of_returns", "intensity")}
    t = time.perf_counter()
    cls = classify.classify_points(a["x"], a["y"], a["z"], a["return_number"], a["number_of_returns"], a["intensity"])
    return score(cls, truth, seconds=time.perf_counter() - t)


def synthetic() -> dict:
    import test_classify_bridge as tb

    out = {}
    for seed in (11, 12, 13):
        x, y, z, lab = tb.footbridge_scene(seed)
        t = time.perf_counter()
        cls = classify.classify_points(x, y, z)
        deck = lab == 1
        out[f"footbridge_seed{seed}"] = {"seconds": round(time.perf_counter() - t, 1),
                                         "bridge_deck": int(np.sum(cls == classify.BRIDGE_DECK)),
                                         "deck": pa_ua(cls == classify.BRIDGE_DECK, deck),
                                         "deck_above_1_5_m_pa_pct": round(100.0 * np.mean(
                                             cls[deck & (z > 1.5)] == classify.BRIDGE_DECK), 2),
                                         "deck_off_the_deck": int(np.sum((cls == classify.BRIDGE_DECK) & ~deck))}
    x, y, z, deck, strip = tb.bridge_scene()
    cls = classify.classify_points(x, y, z)
    out["canal_bridge"] = {"bridge_deck": int(np.sum(cls == classify.BRIDGE_DECK)),
                           "deck": pa_ua(cls == classify.BRIDGE_DECK, deck)}
    return out


def others() -> dict:
    """Bridge-deck returns and the classes' SHA-256 on the remaining real sets (no bridges known)."""
    import hashlib

    from lidar_common import SAMPLES

    paths = {**{f"isprs_{k}": DATA / "isprs_filtertest" / f"{k}-utm.laz" for k in SAMPLES},
             "lidr_topography": DATA / "lidr_topography" / "Topography.laz",
             "lidr_mixedconifer": DATA / "lidr_mixedconifer" / "MixedConifer.laz",
             "laspy_nebraska": DATA / "laspy_nebraska" / "file_with_both_wkt_and_geotiff_vlrs.las"}
    rows = {}
    for name, path in paths.items():
        c, cls, sec = real(path)
        rows[name] = {"points": len(cls), "bridge_deck": int(np.sum(cls == classify.BRIDGE_DECK)),
                      "sha256": hashlib.sha256(cls.tobytes()).hexdigest()}
        print(name, rows[name], flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True)
    ap.add_argument("--demo", type=Path)
    ap.add_argument("--sim", type=Path, action="append", default=[],
                    help="Other simulated projects (aerotri sim --preset P --seed S DIR), scored as the demo.")
    ap.add_argument("--others", action="store_true", help="only the remaining real sets (ISPRS, Topography, "
                                                               "MixedConifer, Nebraska), stored under others")
    args = ap.parse_args()
    res = {"code": str(Path(classify.__file__).parent)}
    if args.others:
        res = {"others": others()}
        return store(args.label, res)
    if args.demo:
        res["demo"] = demo(args.demo)
        print("demo", res["demo"], flush=True)
    for project in args.sim:
        res[f"sim_{project.name}"] = demo(project)
        print(project.name, res[f"sim_{project.name}"], flush=True)
    c, cls, sec = real(DATA / "ahn3_delft" / "ahn3_cropped_1.laz", "EPSG:28992")
    res["ahn3_delft"] = score(cls, c.classification, deck_ref=c.classification == 26, seconds=sec)
    print("ahn3", res["ahn3_delft"], flush=True)
    import eval_false_classes as efc

    c, cls, sec = real(DATA / "autzen" / "autzen_trim.laz")
    fb = efc.footbridge(c)
    res["autzen"] = score(cls, c.classification, seconds=sec)
    res["autzen"]["footbridge_corridor"] = {"points": int(fb.sum()),
                                            "bridge_deck": int(np.sum(fb & (cls == classify.BRIDGE_DECK))),
                                            "deck_outside": int(np.sum(~fb & (cls == classify.BRIDGE_DECK)))}
    print("autzen", res["autzen"], flush=True)
    res["synthetic"] = synthetic()
    print("synthetic", res["synthetic"], flush=True)
    return store(args.label, res)


def store(label: str, res: dict) -> int:
    """Merge ``res`` into the label's rows of OUT (written atomically)."""
    old = json.loads(OUT.read_text()) if OUT.exists() else {}
    old.setdefault("what", __doc__.splitlines()[0])
    old.setdefault("command", "see the docstring of bench/eval_bridge_decks.py (--label main and --label branch)")
    old.setdefault(label, {}).update(res)
    tmp = OUT.with_suffix(".tmp")
    tmp.write_text(json.dumps(old, indent=1) + "\n")
    tmp.replace(OUT)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
