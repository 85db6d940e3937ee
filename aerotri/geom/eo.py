"""Exterior orientation and GNSS text files (architecture doc: project folder).

``eo.txt``: ``image_id X Y Z omega phi kappa`` (metres, degrees), optionally followed by standard
deviations ``sX sY sZ somega sphi skappa``. ``gnss.txt``: ``image_id X Y Z [sX sY sZ]``.
Lines starting with ``#`` are comments.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from aerotri.core.errors import CrsError, InputError
from aerotri.core.textio import read_text
from aerotri.geom.rotation import rotation_matrix_opk
from aerotri.core.atomic import write_text_atomic


@dataclasses.dataclass
class ExteriorOrientations:
    """Exterior orientations of a block; arrays are aligned with ``image_id``."""

    image_id: list[str]
    centre_m: np.ndarray  # (N, 3) projection centres X Y Z
    opk_deg: np.ndarray  # (N, 3) omega phi kappa
    sigma: np.ndarray | None = None  # (N, 6) sX sY sZ (m) somega sphi skappa (deg)

    def __len__(self):
        return len(self.image_id)

    def rotation(self, i: int) -> np.ndarray:
        return rotation_matrix_opk(*self.opk_deg[i])

    def rotations(self) -> np.ndarray:
        return rotation_matrix_opk(self.opk_deg[:, 0], self.opk_deg[:, 1], self.opk_deg[:, 2])

    def rows(self, image_ids) -> np.ndarray:
        """The row numbers (int) of ``image_ids`` (KeyError naming the first id that has no orientation)."""
        return _rows(self.image_id, image_ids, "orientation")

    def row(self, image_id: str) -> int:
        return int(self.rows([image_id])[0])


def _rows(ids, wanted, what: str) -> np.ndarray:
    """Row numbers in ``ids`` of the ids ``wanted``, in their order."""
    at = {k: i for i, k in enumerate(ids)}
    try:
        return np.array([at[k] for k in wanted], dtype=np.int64)
    except KeyError as exc:
        raise KeyError(f"image {exc.args[0]!r} has no {what}") from None


def _parse_table(path: Path, min_cols: int, max_cols: int, what: str) -> tuple[list[str], np.ndarray, list[int]]:
    """(ids, values (N, fields - 1), line numbers) of a whitespace table ``image_id v1 v2 ...``."""
    text = read_text(path, f"table ({what})")
    ids, rows, seen = [], [], {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        # (trial s94: a CSV export with its header, 'filename,x,y,z', read "got 1 fields" and nothing more)
        commas = "; the fields are separated by spaces or tabs, and this line has commas (a CSV: replace them)" \
            if "," in s and len(s.replace(",", " ").split()) != len(parts) else ""
        header = "; a header line? start it with # (a comment)" if not ids else ""
        if not (min_cols <= len(parts) <= max_cols):
            raise InputError(f"{path}:{lineno}: expected {what}, got {len(parts)} fields: {s!r}{commas}"
                             + (header if not commas else ""))
        try:
            vals = [float(p) for p in parts[1:]]
        except ValueError:
            raise InputError(f"{path}:{lineno}: non-numeric value in {s!r} (expected {what}){header}") from None
        if not all(math.isfinite(v) for v in vals):
            raise InputError(f"{path}:{lineno}: NaN or infinite value in {s!r}")
        if parts[0] in seen:
            raise InputError(f"{path}:{lineno}: duplicate image id {parts[0]!r} (first on line {seen[parts[0]]})")
        seen[parts[0]] = lineno
        ids.append(parts[0])
        rows.append(vals)
    if not ids:
        raise InputError(f"{path}: no records (expected {what})")
    lines = list(seen.values())
    for r, lineno in zip(rows, lines):
        if len(r) != len(rows[0]):
            raise InputError(f"{path}:{lineno}: {len(r) + 1} fields, but line {lines[0]} has {len(rows[0]) + 1} "
                             f"(expected {what} on every line)")
    return ids, np.array(rows, dtype=float), lines


def check_block_crs(crs, source: str):
    """The project CRS of a photo block as a pyproj CRS: known to PROJ and with map coordinates in
    metres or feet (projected or a local engineering CRS); ``CrsError`` naming ``source`` otherwise
    (e.g. ``P/project.toml [project] crs``): the adjustment and the footprints need x = easting,
    y = northing, not longitude/latitude."""
    from aerotri.geom.crs.definition import crs_label, horizontal_crs, parse_crs

    c = parse_crs(crs, source)
    h = horizontal_crs(c)
    if h.is_vertical:  # (heights only: new-user trial s51, init took EPSG:5703 and match stopped on a traceback)
        raise CrsError(f"{source}: {crs_label(c)} ({c.name}) is a vertical CRS (heights only); the photo block needs a "
                       "projected CRS in metres (e.g. the UTM zone, EPSG:326xx) for gnss.txt and the orientations, "
                       "with the heights' system after a '+' (EPSG:32615+5703) or in [project] heights")
    if h.is_geographic or h.is_geocentric:
        raise CrsError(f"{source}: {crs_label(c)} ({c.name}) is {'geographic' if h.is_geographic else 'geocentric'}; "
                       "the photo block needs a projected CRS in metres (e.g. the UTM zone, EPSG:326xx) for "
                       "gnss.txt and the orientations")
    return c


def check_positions(path, ids, xyz_m, lines, crs) -> None:
    """InputError naming the line whose X, Y cannot be in ``crs`` (swapped X/Y, degrees, another zone)."""
    from aerotri.geom.crs.definition import check_coordinates

    xyz_m = np.asarray(xyz_m, dtype=float)
    check_coordinates(crs, xyz_m[:, 0], xyz_m[:, 1], str(path),
                      [f"line {ln} (image {i})" for ln, i in zip(lines, ids)])


def read_eo(path, crs=None) -> ExteriorOrientations:
    """``eo.txt``; with ``crs`` (pyproj CRS) the projection centres are checked against it."""
    path = Path(path)
    ids, a, lines = _parse_table(path, 7, 13, "image_id X Y Z omega phi kappa [sX sY sZ somega sphi skappa]")
    if a.shape[1] not in (6, 12):
        raise InputError(f"{path}:{lines[0]}: expected 7 or 13 fields per line "
                         f"(image_id X Y Z omega phi kappa [sX sY sZ somega sphi skappa]), got {a.shape[1] + 1}")
    if crs is not None:
        check_positions(path, ids, a[:, :3], lines, crs)
    return ExteriorOrientations(ids, a[:, :3].copy(), a[:, 3:6].copy(), a[:, 6:12].copy() if a.shape[1] == 12 else None)


def format_eo(eo: ExteriorOrientations, notes: tuple[str, ...] = ()) -> str:
    """eo.txt's text; ``notes``: comment lines above the header (e.g. that the heights are relative)."""
    head = "# image_id X_m Y_m Z_m omega_deg phi_deg kappa_deg"
    if eo.sigma is not None:
        head += " sX_m sY_m sZ_m somega_deg sphi_deg skappa_deg"
    lines = [f"# {n}" for n in notes] + [head]
    for i, iid in enumerate(eo.image_id):
        X, Y, Z = eo.centre_m[i]
        o, p, k = eo.opk_deg[i]
        s = f"{iid} {X:.4f} {Y:.4f} {Z:.4f} {o:.7f} {p:.7f} {k:.7f}"
        if eo.sigma is not None:
            s += " " + " ".join(f"{v:.4f}" for v in eo.sigma[i, :3]) + " " + " ".join(f"{v:.7f}" for v in eo.sigma[i, 3:])
        lines.append(s)
    return "\n".join(lines) + "\n"


def write_eo(path, eo: ExteriorOrientations) -> None:
    write_text_atomic(path, format_eo(eo))


@dataclasses.dataclass
class GnssPositions:
    image_id: list[str]
    position_m: np.ndarray  # (N, 3)
    sigma_m: np.ndarray | None = None  # (N, 3)

    def rows(self, image_ids) -> np.ndarray:
        """The row numbers (int) of ``image_ids`` (KeyError naming the first id that has no position)."""
        return _rows(self.image_id, image_ids, "GNSS position")


def read_gnss(path, crs=None) -> GnssPositions:
    """``gnss.txt``; with ``crs`` (pyproj CRS) the positions are checked against it (swapped X/Y,
    degrees or another zone stop here, naming the line)."""
    path = Path(path)
    ids, a, lines = _parse_table(path, 4, 7, "image_id X Y Z [sX sY sZ]")
    if a.shape[1] not in (3, 6):
        raise InputError(f"{path}:{lines[0]}: expected 4 or 7 fields per line (image_id X Y Z [sX sY sZ]), "
                         f"got {a.shape[1] + 1}")
    sig = a[:, 3:6].copy() if a.shape[1] == 6 else None
    if sig is not None and np.any(sig <= 0):
        k = int(np.argmax(np.any(sig <= 0, axis=1)))
        raise InputError(f"{path}:{lines[k]}: standard deviations sX sY sZ of image {ids[k]} must be positive, "
                         f"got {' '.join(f'{v:g}' for v in sig[k])}")
    if crs is not None:
        check_positions(path, ids, a[:, :3], lines, crs)
    return GnssPositions(ids, a[:, :3].copy(), sig)


def format_gnss(g: GnssPositions, comment: str = "") -> str:
    """``gnss.txt`` text (``comment`` appended to the header line)."""
    lines = ["# image_id X_m Y_m Z_m" + (" sX_m sY_m sZ_m" if g.sigma_m is not None else "") + comment]
    for i, iid in enumerate(g.image_id):
        s = f"{iid} " + " ".join(f"{v:.4f}" for v in g.position_m[i])
        if g.sigma_m is not None:
            s += " " + " ".join(f"{v:.4f}" for v in g.sigma_m[i])
        lines.append(s)
    return "\n".join(lines) + "\n"


def write_gnss(path, g: GnssPositions) -> None:
    write_text_atomic(path, format_gnss(g))
