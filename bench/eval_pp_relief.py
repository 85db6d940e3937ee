"""A principal point flagged against a GNSS offset fixed in the camera, judged by its predicted effect on ground
(aerotri.adjust.determinability ``PP_RELIEF_PLAN_FRACTION``, pp-relief; since pp-predictor the tie points' RMS plan
change under the offset named, from the normal equations, ``predicted_plan_m``; pp-relief's offset x half the 5-95 %
relief / depth kept beside it as ``predicted_plan_m_pp_relief``). Reviewer 13's
blocks (/work/tmp/review-s13/pp.py): 3 x 6 DMC frames at 1,000 m flown in alternating directions, GNSS only, 30 check
points, the a-priori camera the true one; relief 60 m and 2 m; seeds 0-11, each with a 0.01 s lag at 70 m/s (0.7 m
along the track) and without. Per seed: the verdict, whether the relief finding is a weakness, the predicted plan
effect (the offset named x half the tie points' 5-95 % height range / their depth), and the measured one: the check
points' adjusted positions with the lag minus without (plan RMS, and the 90th percentile of the plan change), and
the check RMS E / N / U of both. The fraction (1/3 of the 1:5000 flat plan limit 0.35 m) was set before this ran;
judged also against 1:2000 flat (0.14 m). How the prediction scales: relief 15 and 30 m on seeds 0-5, 120 m on seeds
0-11, 180 m on seeds 0-5. pp-predictor's design was looked at on seeds 0-2 of 60 m and 0-5 of 120 m (the offset
estimate's limit is PP_MOVE_SIGMAS, not tuned); everything else is scored only. ``camera_off``: no lag, the camera
file's principal point 0.06 mm (5 px) off the true one along y, 120 m relief, seeds 0-5: the block's own offset
estimate should find no offset (a flag there is false under 0.9 correlation). s18-fixes, scored only on seeds and
reliefs review 18 did not look at: ``camera_off_lag`` (the lag and the camera file 5 px off together), ``no_lag``
(false flags) and ``strip_shifts`` (unmodelled 0.3 m GNSS shifts per strip; the reference the clean block).
Writes bench/results/pp_relief.json (or the path given). Run: .venv/bin/python bench/eval_pp_relief.py (about 5
min)."""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "aerotri" / "adjust"))

import test_determinability as T  # noqa: E402
from aerotri.adjust.pipeline import AdjustSettings, adjust_project  # noqa: E402
from aerotri.adjust.report import build_report  # noqa: E402
from aerotri.core.records import to_record  # noqa: E402
from aerotri.geom.camera import dmc_camera  # noqa: E402
from aerotri.sim.observations import geometric_block, write_block_project, write_truth_observations  # noqa: E402

SEEDS = range(12)


_SOLVED: dict = {}


def solve(seed: int, lag_s: float, relief_m: float, ppy_mm: float = 0.0, shift_sigma_m: float = 0.0):
    key = (seed, lag_s, relief_m, ppy_mm, shift_sigma_m)
    if key not in _SOLVED:
        _SOLVED[key] = _solve(*key)
    return _SOLVED[key]


def _solve(seed: int, lag_s: float, relief_m: float, ppy_mm: float, shift_sigma_m: float):
    with tempfile.TemporaryDirectory() as d:
        block = geometric_block(3, 6, seed=seed, camera_true=dmc_camera(), relief_m=relief_m, tilt_sigma_deg=0.3,
                                gnss_shift_sigma_m=shift_sigma_m, gnss_drift_sigma_m_per_km=0.0,
                                lever_arm_m=(0.0, 0.0, 0.0))
        block.camera_nominal = dataclasses.replace(dmc_camera(), ppy_mm=ppy_mm)
        east = np.asarray(block.strip) % 2 == 0
        block.gnss_local = block.gnss_local + np.outer(np.where(east, 1.0, -1.0) * T.LAG_SPEED_MPS * lag_s,
                                                       [1.0, 0.0, 0.0])
        root = write_block_project(block, Path(d) / "p")
        write_truth_observations(root, tie_sigma_px=T.SIGMA_PX, n_control=0, n_check=30, points_per_image=100,
                                 seed=seed)
        ba = adjust_project(root, AdjustSettings(image_sigma_px=T.SIGMA_PX, self_calibration=("pp",),
                                                 use_control=True))
        ks = to_record(build_report(ba))["key_statistics"]
        ks["relief_weak_1to2000"] = to_record(build_report(ba, map_scale="1:2000"))["key_statistics"][
            "calibration_relief_weak"] == ["pp"]
    return ba, ks


def pp_relief_prediction(ba, pp) -> float | None:
    """pp-relief's predicted plan effect: the offset the v0 / u0 move names x half the tie points' 5-95 % height
    range / their median depth (the larger axis), for any block whose principal point moved, flagged or not."""
    b, st = ba.block, ba.result.state
    tie = np.unique(b.obs_point[~np.isin(b.obs_point, b.control_point)])
    half = float(np.subtract(*np.percentile(st.points[tie, 2], [95, 5])) / 2)
    out = [abs((pp.estimate[f"{n}_px"] - pp.apriori[f"{n}_px"]) / pp.gnss_offset_px_per_m[a]) * half
           / ba.result.calibration.depth_m for a, n in enumerate(("u0", "v0"))
           if abs(pp.estimate[f"{n}_px"] - pp.apriori[f"{n}_px"]) > 5 * pp.sigma[f"{n}_px"]]
    return round(max(out), 4) if out else None


def row(seed: int, relief_m: float, lag_s: float = T.LAG_S, ppy_mm: float = 0.0, shift_sigma_m: float = 0.0) -> dict:
    # the reference: the same block and noise with no lag, the true camera file and no GNSS shifts
    (ba, ks), (ba0, ks0) = solve(seed, lag_s, relief_m, ppy_mm, shift_sigma_m), solve(seed, 0.0, relief_m)
    pp = {c.group: c for c in ba.calibration_checks}["pp"]
    pp0 = {c.group: c for c in ba0.calibration_checks}["pp"]
    ids = sorted(ba.check)
    adj = np.array([ba.check[i]["adjusted_m"] for i in ids]) - np.array([ba0.check[i]["adjusted_m"] for i in ids])
    plan = np.hypot(adj[:, 0], adj[:, 1])

    def rms(b) -> list:
        d = np.array([np.subtract(c["adjusted_m"], c["measured_m"]) for c in b.check.values()])
        return [round(float(x), 4) for x in np.sqrt(np.mean(d ** 2, axis=0))]

    return {"seed": seed, "action": pp.action, "action_without_lag": pp0.action, "verdict": ks["verdict"],
            "verdict_without_lag": ks0["verdict"],
            "relief_weak": ks["calibration_relief_weak"] == ["pp"], "relief_weak_1to2000": ks["relief_weak_1to2000"],
            "v0_move_sigmas": round((pp.estimate["v0_px"] - pp.apriori["v0_px"]) / pp.sigma["v0_px"], 1),
            "v0_offset_correlation": round(pp.gnss_offset_correlation[1], 4),
            "v0_offset_named_m": round((pp.estimate["v0_px"] - pp.apriori["v0_px"]) / pp.gnss_offset_px_per_m[1], 3),
            "y_offset_estimate_m": round(pp.gnss_offset_estimate_m[1], 3),
            "y_offset_estimate_sigma_m": round(pp.gnss_offset_estimate_sigma_m[1], 3),
            "y_offset_estimate_without_lag_m": round(pp0.gnss_offset_estimate_m[1], 3),
            "x_offset_estimate_m": round(pp.gnss_offset_estimate_m[0], 3),
            "x_offset_estimate_sigma_m": round(pp.gnss_offset_estimate_sigma_m[0], 3),
            "offset_estimate_sigmas_off_zero": [round(abs(e) / s, 1) for e, s in zip(pp.gnss_offset_estimate_m,
                                                                                     pp.gnss_offset_estimate_sigma_m)],
            "predicted_plan_m": None if _effect(pp) is None else round(_effect(pp), 4),
            "predicted_plan_m_pp_relief": pp_relief_prediction(ba, pp),
            "measured_plan_change_rms_m": round(float(np.sqrt(np.mean(plan ** 2))), 4),
            "measured_plan_change_p90_m": round(float(np.percentile(plan, 90)), 4),
            "measured_change_rms_enu_m": [round(float(x), 4) for x in np.sqrt(np.mean(adj ** 2, axis=0))],
            "check_rms_enu_m": rms(ba), "check_rms_enu_without_lag_m": rms(ba0)}


def _effect(pp) -> float | None:
    """The flag's predicted plan effect (m; None: no flag or none named), by the field's name before and after
    s18-fixes (``relief_plan_m`` then ``gnss_offset_plan_effect_m``), so that the bench runs on either."""
    return getattr(pp, "gnss_offset_plan_effect_m", getattr(pp, "relief_plan_m", None))


def case(relief_m: float, seeds=SEEDS, **kw) -> dict:
    rows = [row(s, relief_m, **kw) for s in seeds]
    pick = lambda k: [r[k] for r in rows if r[k] is not None]  # noqa: E731
    mean3 = lambda k: [round(float(x), 4) for x in np.mean([r[k] for r in rows], axis=0)]  # noqa: E731

    def ratio(k: str) -> dict:  # measured plan change RMS over a prediction, on the seeds it exists for
        q = [r["measured_plan_change_rms_m"] / r[k] for r in rows if r[k]]
        return {"median": round(float(np.median(q)), 2), "min": round(float(np.min(q)), 2),
                "max": round(float(np.max(q)), 2), "seeds": len(q)} if q else {}

    third = {"1:5000": 0.35 / 3, "1:2000": 0.14 / 3}
    return {"relief_m": relief_m, "seeds": len(rows), **kw,
            "flagged": sum(r["action"] == "flagged" for r in rows),
            "flagged_without_lag": sum(r["action_without_lag"] == "flagged" for r in rows),
            "relief_weak": sum(r["relief_weak"] for r in rows),
            "relief_weak_1to2000": sum(r["relief_weak_1to2000"] for r in rows),
            # the seeds whose measured change passes a third of the plan limit: what a weakness should catch
            "measured_over_third": {s: sum(r["measured_plan_change_rms_m"] > t for r in rows)
                                    for s, t in third.items()},
            # per seed, a weakness against the measured change over the third: hit, false (weak, not over), miss
            "weak_vs_measured": {s: {"hit": sum(r[k] and r["measured_plan_change_rms_m"] > t for r in rows),
                                     "false": sum(r[k] and not r["measured_plan_change_rms_m"] > t for r in rows),
                                     "miss": sum(not r[k] and r["measured_plan_change_rms_m"] > t for r in rows)}
                                 for (s, t), k in zip(third.items(), ("relief_weak", "relief_weak_1to2000"))},
            "successful": sum(r["verdict"] == "successful" for r in rows),
            "successful_without_lag": sum(r["verdict_without_lag"] == "successful" for r in rows),
            "predicted_plan_m_median": round(float(np.median(pick("predicted_plan_m"))), 4) if pick(
                "predicted_plan_m") else None,
            "measured_plan_change_rms_m_median": round(float(np.median(pick("measured_plan_change_rms_m"))), 4),
            "measured_plan_change_p90_m_median": round(float(np.median(pick("measured_plan_change_p90_m"))), 4),
            "measured_over_predicted": ratio("predicted_plan_m"),
            "measured_over_predicted_pp_relief": ratio("predicted_plan_m_pp_relief"),
            "measured_plan_change_rms_m_not_flagged": [r["measured_plan_change_rms_m"] for r in rows
                                                       if r["action"] != "flagged"],
            "check_rms_enu_m_mean": mean3("check_rms_enu_m"),
            "check_rms_enu_without_lag_m_mean": mean3("check_rms_enu_without_lag_m"), "rows": rows}


def main() -> None:
    from aerotri.adjust.determinability import PP_RELIEF_PLAN_FRACTION

    out = {"fraction_of_plan_limit": PP_RELIEF_PLAN_FRACTION, "plan_limit_m": 0.35, "tolerances": "1:5000 flat",
           "injected_offset_m": T.LAG_SPEED_MPS * T.LAG_S, "cases": [case(60.0), case(2.0)],
           # how the prediction scales with the relief
           "scaling": [case(15.0, range(6)), case(30.0, range(6)), case(120.0), case(180.0, range(6))],
           # no lag, the camera file's principal point off by 5 px along y: no offset to find
           "camera_off": [case(120.0, range(6), lag_s=0.0, ppy_mm=0.06)],
           # s18-fixes, scored only (review 18 looked at seeds 0-5 of 120 and 60 m, 0-19 without a lag): the lag
           # and the camera file's principal point 5 px off together (the move names the lag's share minus the
           # camera file's error); no lag on other seeds (false flags); unmodelled 0.3 m GNSS shifts per strip
           "camera_off_lag": [case(120.0, range(6, 12), ppy_mm=0.06), case(60.0, range(6, 12), ppy_mm=0.06),
                              case(90.0, range(6), ppy_mm=-0.06), case(180.0, range(6, 12), ppy_mm=0.06)],
           "no_lag": [case(120.0, range(20, 40), lag_s=0.0), case(60.0, range(20, 30), lag_s=0.0),
                      case(90.0, range(10), lag_s=0.0)],
           "strip_shifts": [case(120.0, range(6, 12), lag_s=0.0, shift_sigma_m=0.3),
                            case(2.0, range(6, 12), lag_s=0.0, shift_sigma_m=0.3)]}
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent / "results" / "pp_relief.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=1) + "\n")
    tmp.replace(path)
    for c in out["cases"] + out["scaling"] + out["camera_off"] + out["camera_off_lag"] + out["no_lag"] + out[
            "strip_shifts"]:
        print({k: v for k, v in c.items() if k != "rows"})


if __name__ == "__main__":
    main()
