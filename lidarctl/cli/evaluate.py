"""``lidarctl evaluate``: classes against a reference (per point or per area of a map)."""

from __future__ import annotations

import click

from aerotri.core.atomic import refuse_input_as_output
from aerotri.core.commands import Command, at_least, fraction, positive
from lidarctl.checks.map_accuracy import MapEvalSettings


def _parse_map(text: str | None, option: str) -> dict:
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        try:
            a, b = item.split(":")
            a, b = int(a), int(b)
        except ValueError:
            raise click.BadParameter(f"{item!r}: expected FROM:TO class pairs, e.g. 3:1,4:1", param_hint=option) from None
        if not (0 <= a <= 255 and 0 <= b <= 255):  # ASPRS codes are bytes (TO 255: leave out)
            raise click.BadParameter(f"{item!r}: class codes are 0-255", param_hint=option)
        if a in out:
            raise click.BadParameter(f"{item!r}: class {a} mapped twice", param_hint=option)
        out[a] = b
    return out


@click.command(cls=Command)
@click.argument("pred_paths", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None,
              help="Truth cloud with the same points in the same order (point-by-point filter test).")
@click.option("--reference", "reference_path", type=click.Path(dir_okay=False), default=None,
              help="Reference map: class GeoTIFF (ASPRS codes) or class polygons (.gpkg/.geojson); PRED is then a "
                   "classified cloud or a class GeoTIFF, scored per cell and per building.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None, help="Write the numbers as JSON.")
@click.option("--map-pred", default=None,
              help="Class mapping for the prediction, e.g. 3:1,4:1,5:1 (TO 255: leave out); --truth: replaces the "
                   "mapping onto a coarser truth's class 1.")
@click.option("--map-truth", default=None, help="Class mapping for the truth or reference, e.g. 0:1.")
@click.option("--res-m", "res_m", type=positive(), default=None,
              help="--reference: cell size in metres [0.5; with a raster: the raster's cells, or a raster sampled at "
                   "the centres of cells of this size, e.g. to match a sparse cloud].")
@click.option("--class-field", default=MapEvalSettings.class_field, show_default=True,
              help="--reference polygons: the attribute holding the class (ASPRS code or name: building, tree, "
                   "grass, road, bare ground, water).")
@click.option("--reference-class", default=None,
              help="--reference polygons: one class for every polygon (e.g. building for footprints).")
@click.option("--min-overlap", type=fraction(open_low=True, open_high=False), default=MapEvalSettings.min_overlap,
              show_default=True, help="--reference: share of a building's area that must overlap to count it as "
                                      "found (reference) or correct (detected).")
@click.option("--min-building-m2", type=at_least(0), default=MapEvalSettings.min_building_m2,
              show_default=True, help="--reference: buildings smaller than this (m2) are not counted per building.")
@click.option("--within", default=None,
              help="--reference: score only inside the polygons of this file, or 'hull': inside the convex hulls "
                   "of the reference polygons' blocks (a reference that maps only part of the area).")
@click.option("--crs", default=None, help="--reference only: CRS (EPSG:code) of inputs that have none.")
def evaluate(*, pred_paths, truth_path, reference_path, json_path, map_pred, map_truth, res_m, class_field,
             reference_class, min_overlap, min_building_m2, within, crs):
    """Accuracy of the classification PRED_PATHS (one file; --reference: also classified strips).

    --truth: a cloud against its truth cloud point by point: type I/II/total error and kappa (ground =
    classes 2, 9) and the confusion matrix; against a truth with class 1 and no vegetation class (AHN3: 1 2 6 9 26)
    our classes 3 4 5 7 17 18 count as its 1 (said, with the figures before the mapping).

    --reference: a classified cloud (the class of each cell's highest point, noise left out; medium
    vegetation counts as tree) or a class raster against a reference map, as the seeds report it:
    pixel confusion matrix over building, tree, grass, road, bare ground, water with producer's,
    user's and overall accuracy and kappa; buildings per area (type I/II, overall) and per building
    (completeness and correctness by count).
    """
    from aerotri.core.atomic import write_text_atomic

    _check_evaluate_paths(pred_paths, truth_path, reference_path, json_path, within)
    if crs is not None and reference_path is None:
        from aerotri.core.errors import OptionError

        # s27: it was ignored without a word; the truth is compared point by point, by record
        raise OptionError("applies to --reference only: --truth compares the two clouds point by point (record by "
                          "record), not by their coordinates; leave --crs out", param="--crs")
    maps = _parse_map(map_pred, "--map-pred"), _parse_map(map_truth, "--map-truth")
    if reference_path is not None:
        text, json_text = _evaluate_map(pred_paths, reference_path, MapEvalSettings(
            res_m=res_m, min_overlap=min_overlap, min_building_m2=min_building_m2, class_field=class_field,
            reference_class=reference_class, map_pred=maps[0], map_ref=maps[1], crs=crs, within=within))
    else:
        text, json_text = _evaluate_truth(pred_paths, truth_path, *maps)
    click.echo(text)
    if json_path:
        write_text_atomic(json_path, json_text)


def _check_evaluate_paths(pred_paths, truth_path, reference_path, json_path, within) -> None:
    """One of --truth and --reference; --json replaces no input."""
    from aerotri.core.errors import OptionError

    if (truth_path is None) == (reference_path is None):
        raise OptionError("give either --truth (a truth cloud) or --reference (a reference map)",
                          param="--truth" if truth_path is None else "--reference")
    if json_path:
        refuse_input_as_output(json_path, [*pred_paths, truth_path, reference_path,
                                           None if within in (None, "hull") else within], "--json")


def _evaluate_map(pred_paths, reference_path, settings) -> tuple[str, str]:
    """``lidarctl evaluate --reference``: (the report, the --json file's text)."""
    from lidarctl.checks import map_accuracy as ma

    result = ma.evaluate_map(pred_paths, reference_path, settings)
    return ma.format_map_report(result), result.to_json()


def _evaluate_truth(pred_paths, truth_path, map_pred: dict, map_truth: dict) -> tuple[str, str]:
    """``lidarctl evaluate --truth``: (the report, the --json file's text)."""
    from aerotri.core.errors import OptionError
    from lidarctl.checks import classes as ev

    if len(pred_paths) != 1:
        raise OptionError(f"--truth: one classified file, not {len(pred_paths)}", param="--truth")
    result = ev.evaluate_files(pred_paths[0], truth_path, map_pred, map_truth)
    text = "\n".join([ev.format_filter_table({"ground": result.filter_test}), "",
                      ev.format_confusion(result.confusion), *ev.format_class_map(result)]
                     + _truth_notes(result.confusion, result.class_map))
    return text, result.to_json()


def _truth_notes(conf, class_map: dict | None = None) -> list[str]:
    """What the numbers against a truth cloud do not say: its class 1 may hold ground (a production classification:
    Autzen, lidR's topography), and a truth of ground and one other class makes the matrix compare classes it has
    no label for (the ISPRS filter test's 0 / 2). ``class_map``: the mapping already applied to the prediction
    (a truth in a coarser scheme), which the --map-pred offered must repeat (it replaces it)."""
    truth = [c for c, row in zip(conf.classes, conf.matrix) if sum(row) > 0]
    pred = [c for c, col in zip(conf.classes, zip(*conf.matrix)) if sum(col) > 0]
    notes = []
    if 1 in truth:
        notes.append("note: the truth's class 1 (unclassified) counts as object: where it also holds ground (a "
                     "production classification), type II and total overstate the errors; type I does not")
    other = [c for c in truth if c not in (2, 9)]
    if len(other) == 1 and len(set(pred) - {2, 9, other[0]}) > 0:
        mapping = {**{int(a): b for a, b in (class_map or {}).items()},
                   **{c: other[0] for c in sorted(set(pred) - {2, 9, other[0]})}}
        notes.append(f"note: the truth labels ground and class {other[0]} only: the overall accuracy and kappa above "
                     f"count every other predicted class as wrong; --map-pred "
                     + ",".join(f"{a}:{b}" for a, b in sorted(mapping.items())) + " gives the two-class matrix")
    return notes
