"""Foliage beyond a roof's reach (``ClassifySettings.foliage_beyond_roof_reach``, stop 117) chosen across data sets,
leave one set out (issue 44's discipline: the choice made without the set it is scored on).

The sets: AHN3 Delft against the BGT footprints (its measure the lowest of area completeness and correctness over the
four footprint parts, bench/results/buildings_bgt.json: the shipped rule set with and without the rule) and IGN LiDAR
HD's labelled test tiles that hold buildings (per point against IGN's labels, the lower of building producer's and
user's accuracy, bench/results/ground_more_data.json: the shipped defaults and ``rules_off.foliage_beyond_reach``).
Per held-out set, the rule is on when the training sets' measures, compared lowest first, are higher with it (the
lowest decides, and where it ties, the next lowest: the decimated tiles, whose buildings no rule finds, are the lowest
and the rule changes none of them; all tied keeps it off, the older classification); the held-out set is scored once
with that choice. Nothing is classified here:
run bench/eval_buildings_bgt.py --add-rules and bench/eval_ground_more_data.py --fetched DIR first.

The rule was designed looking at IGN Isère's crowns (and at the cell statistics of Montpellier's false building
cells); its figures there are not free of that. Writes bench/results/foliage_beyond_reach.json.
Run: .venv/bin/python bench/eval_foliage_beyond_reach.py
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_buildings_bgt import PARTS, _worst  # noqa: E402
from results_json import read_results, store_result  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SHIPPED_SET = "sheds + crowns + pierced 0.1 + completion stop"
WITH_RULE = SHIPPED_SET + " + foliage beyond reach"
LOOKED_AT = ("ign_isere_buildings", "ign_montpellier")   # the rule's design sets


def ahn3_measures(bgt: dict) -> dict:
    """{"off": ..., "on": ...}: the lowest area completeness / correctness over the footprint parts (%)."""
    sets = bgt["rules_nested"]["rule_sets"]
    return {state: _worst(sets[name]["footprint_parts"], PARTS)
            for state, name in (("off", SHIPPED_SET), ("on", WITH_RULE))}


def ign_measures(more: dict) -> dict:
    """{set: {"off": ..., "on": ...}}: min(building PA, UA) per point (%) of the IGN sets that hold buildings."""
    out = {}
    for name, r in more.items():
        if not name.startswith("ign_") or r.get("building_ua_pct") is None or "building_pa_pct" not in r:
            continue
        off = r["rules_off"]["foliage_beyond_reach"]
        out[name] = {"on": min(r["building_pa_pct"], r["building_ua_pct"]),
                     "off": min(off["building_pa_pct"], off["building_ua_pct"] or 0.0),
                     "pa_ua_on": [r["building_pa_pct"], r["building_ua_pct"]],
                     "pa_ua_off": [off["building_pa_pct"], off["building_ua_pct"]]}
    return out


def choose(train: dict) -> tuple[str, dict]:
    """("on" or "off", how): the training sets' measures compared lowest first (leximin): the lowest decides, and
    where it ties (a set the rule does not change, e.g. a decimated tile whose buildings no rule finds) the next
    lowest, and so on; all tied: off. ``how``: the lowest each way and the set that decided (None: all tied)."""
    ranked = {s: sorted((m[s], name) for name, m in train.items()) for s in ("off", "on")}
    how = {"lowest": {s: ranked[s][0][0] for s in ranked}, "decided_by": None, "decided_at_rank": None}
    for rank, ((off, off_name), (on, on_name)) in enumerate(zip(ranked["off"], ranked["on"])):
        if on != off:
            how["decided_by"], how["decided_at_rank"] = (off_name if off < on else on_name), rank
            return ("on" if on > off else "off"), how
    return "off", how


def leave_one_set_out(measures: dict) -> dict:
    """Per held-out set: the choice on the others and the held-out score."""
    held = {}
    for name in measures:
        chosen, how = choose({k: m for k, m in measures.items() if k != name})
        held[name] = {"chosen": chosen, "training": how, "held_out_measure": measures[name][chosen],
                      "without_the_rule": measures[name]["off"], "rule_designed_looking_at_it": name in LOOKED_AT}
    return held


def main() -> int:
    bgt = read_results(RESULTS / "buildings_bgt.json")
    more = read_results(RESULTS / "ground_more_data.json")
    if WITH_RULE not in bgt.get("rules_nested", {}).get("rule_sets", {}):
        print(f"buildings_bgt.json has no rule set {WITH_RULE!r}: run bench/eval_buildings_bgt.py --add-rules first")
        return 2
    if not any("foliage_beyond_reach" in r.get("rules_off", {}) for r in more.values() if isinstance(r, dict)):
        print("ground_more_data.json has no rules_off.foliage_beyond_reach: "
              "run bench/eval_ground_more_data.py --fetched DIR")
        return 2
    measures = {"ahn3_bgt_footprint_parts": ahn3_measures(bgt), **ign_measures(more)}
    held = leave_one_set_out(measures)
    result = {"definitions": __doc__.split("\n\n")[1].replace("\n", " "), "measures_pct": measures,
              "held_out": held, "chosen_on_all_sets": choose(measures)[0],
              "folds_choosing_on": sum(v["chosen"] == "on" for v in held.values()), "folds": len(held),
              # the lowest training set alone (the maximin without its tie-break) decides in these folds
              "folds_decided_by_the_lowest_set": sum(v["training"]["decided_at_rank"] == 0 for v in held.values())}
    for name, v in held.items():
        print(f"held out {name}: rule {v['chosen']} (decided by {v['training']['decided_by']}), held-out measure "
              f"{v['held_out_measure']:.2f} % (without the rule "
              f"{v['without_the_rule']:.2f} %)" + ("; designed looking at it" * v["rule_designed_looking_at_it"]))
    print(f"chosen on all sets: {result['chosen_on_all_sets']}; "
          f"{result['folds_choosing_on']} of {result['folds']} folds on")
    store_result(RESULTS / "foliage_beyond_reach.json", result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
