"""The resumable stage runner: stamps, skipping what is up to date, the summary table.

A stage is skipped when its stamp (``work/stages/<stage>.json``) records the same input files (content
hash, a SQLite file's without the header fields a reader changes; size and modification time for other files over
64 MiB), options and algorithm versions (``Stage.versions``: the
constants next to the code, e.g. ``lidarctl.classify.RULES_VERSION``, bumped when its outputs change; a stamp written
before they were recorded runs again, its code unknown) as now and all its outputs exist as it wrote them (same
signature: an output edited or written again by another command since runs the stage again, trial-rerun);
otherwise it runs and writes its outputs and its stamp as one commit (``aerotri.core.atomic.commit_outputs``:
a stage that fails leaves every output of its earlier run as it was). Killing a run leaves finished
stages stamped and the interrupted stage without a stamp and without partial outputs (the next run rolls
back what it had replaced), so a re-run continues there. A stage may also be left out for a reason decided when its turn comes (``skip``:
no LiDAR, no usable corner, no DEM ...); the summary row says why. A stage that finds out only by
running that it has nothing to do (the strip check of a single strip) returns a result with ``why`` (its
``aerotri.chain.results.StageResult``): its row says skipped and why, and its stamp keeps that decision while its inputs stay the same.

What a stage cost (``aerotri.core.resources.measure``: wall and CPU seconds, peak RSS of the process and
of its Dask workers) goes into its stamp (``usage``) and its summary row; every run writes its rows and
the load averages at its start and end to ``work/run_summary.json`` (bench/scale.py reads it).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from aerotri.chain.results import StageResult
from aerotri.core.atomic import commit_outputs, remove_leftovers, write_text_atomic
from aerotri.core.errors import interrupt_of
from aerotri.core.limits import memory_limited, release_freed_memory
from aerotri.core.log import doing
from aerotri.core.project import project_paths
from aerotri.core.resources import measure

_log = logging.getLogger(__name__)


@dataclasses.dataclass
class Stage:
    name: str
    inputs: Callable[[Path], list[Path]]  # files whose change re-runs the stage
    outputs: Callable[[Path], list[Path]]  # files the stage must leave behind
    run: Callable[[Path], StageResult]  # does the work, returns its key numbers for the summary
    options: dict | Callable[[Path], dict] = dataclasses.field(default_factory=dict)  # settings that re-run it
    skip: Callable[[Path], str | None] | None = None  # a reason to leave the stage out, asked when its turn comes
    # the versions of the algorithms that decide its outputs (name -> constant next to the code, "bump when outputs
    # change"): a new version re-runs the stage, the same one keeps it up to date; a callable imports them lazily
    versions: dict | Callable[[], dict] = dataclasses.field(default_factory=dict)
    # why outputs changed by hand are the operator's work, to keep (None: made again): an edited-seamline mosaic
    # (review 41: the next run replaced it with the chain's own, the seam edits lost with one log line)
    hand_made: Callable[[Path], str | None] | None = None
    # why files an output lists (not outputs themselves: ortho/frames/index.json's frame orthos) are not there as it
    # records them (None: they are): trial-overnight, 18 frame orthos deleted kept rectify "up to date", exit 0
    listed_missing: Callable[[Path], str | None] | None = None

    def options_now(self, root: Path) -> dict:
        return self.options(root) if callable(self.options) else self.options

    def versions_now(self) -> dict:
        return _plain(self.versions() if callable(self.versions) else self.versions)


def _key(p: Path, root: Path) -> str:
    """An input's name in a stamp: relative to the project root (so a moved or copied project, or a
    run from another working directory, stays up to date), absolute for files outside it."""
    p, root = Path(p).absolute(), Path(root).absolute()
    try:
        return p.relative_to(root).as_posix()
    except ValueError:
        return str(p.resolve())


def _content(p: Path) -> bytes:
    """The bytes that decide whether an input changed: for a TOML file its parsed values (a comment or
    a reordered key does not re-run the chain), for any other file its bytes."""
    data = p.read_bytes()
    if p.suffix.lower() == ".toml":
        import tomllib

        try:
            return json.dumps(tomllib.loads(data.decode("utf-8")), sort_keys=True, default=str).encode()
        except (UnicodeDecodeError, tomllib.TOMLDecodeError):
            return data
    return data


def _signature(paths: list[Path], root: Path, hash_limit_bytes: int = 64 << 20, before: dict | None = None) -> dict:
    """Content hash of each input up to ``hash_limit_bytes`` (timestamps are too coarse to trust),
    size and modification time beyond that; a SQLite file (a GeoPackage) by its content whatever its size
    (``_sqlite_hash``); keys as ``_key`` names them. ``before``: the stamp's record, whose SQLite files may hold the
    plain hash (or size and time) of stamps written before ``_sqlite_hash``: kept while the file is as it was then."""
    sig = {}
    for p in sorted(paths, key=str):
        k = _key(p, root)
        if p.is_file():
            st = p.stat()
            if _is_sqlite(p):
                sig[k] = _sqlite_hash(p)
                old = (before or {}).get(k)
                if old is not None and old != sig[k] and not str(old).startswith(_SQLITE_PREFIX) and \
                        old == _plain_fingerprint(p, st, hash_limit_bytes):
                    sig[k] = old  # (a stamp of before: the same file)
            else:
                sig[k] = _plain_fingerprint(p, st, hash_limit_bytes)
        else:
            sig[k] = None
    return sig


def _plain_fingerprint(p: Path, st: os.stat_result, hash_limit_bytes: int) -> str | list:
    if st.st_size <= hash_limit_bytes:
        return hashlib.sha1(_content(p)).hexdigest()
    return [st.st_size, st.st_mtime_ns]


_SQLITE_MAGIC = b"SQLite format 3\x00"
_SQLITE_PREFIX = "sqlite:"  # a SQLite file's signature (a stamp's plain hash of one was written before)
# bytes of the 100-byte SQLite header that a reader changes without changing a row (sqlite.org/fileformat.html):
# 18-19 the journal mode (QGIS opens a GeoPackage in WAL mode, and sets it back on closing), 24-27 the file change
# counter, 92-95 the version-valid-for number, 96-99 the SQLite version that last wrote the file
_SQLITE_VOLATILE = ((18, 20), (24, 28), (92, 100))


def _is_sqlite(p: Path) -> bool:
    try:
        with open(p, "rb") as f:
            return f.read(len(_SQLITE_MAGIC)) == _SQLITE_MAGIC
    except OSError:
        return False


def _sqlite_hash(p: Path, chunk_bytes: int = 16 << 20) -> str:
    """The hash of a SQLite file (a GeoPackage: lidar_out/crowns.gpkg, lidar_out/vectors.gpkg) without the header
    fields a reader changes (``_SQLITE_VOLATILE``): QGIS opening the file switches it to WAL mode (-wal and -shm
    beside it) and back when it closes, which changed its bytes and re-ran the stage that wrote it (the LiDAR rasters)
    or read it. Hashed whatever its size: the time of a SQLite file changes by such a read. A non-empty "<file>-wal"
    beside it joins the signature (its size and hash): an edit QGIS has not written back into the file (QGIS still
    open, or a crash left it) is what every reader of the file sees (review 44: rasters and rectify said up to date);
    a reader alone leaves the -wal empty."""
    h = hashlib.sha1()
    with open(p, "rb") as f:
        head = bytearray(f.read(100))
        for a, b in _SQLITE_VOLATILE:
            head[a:b] = bytes(b - a)
        h.update(head)
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    sig = _SQLITE_PREFIX + h.hexdigest()
    wal = p.with_name(p.name + "-wal")
    try:
        with open(wal, "rb") as f:
            w, size = hashlib.sha1(), 0
            while chunk := f.read(chunk_bytes):
                w.update(chunk)
                size += len(chunk)
    except OSError:  # (no -wal: the usual case)
        return sig
    return f"{sig} wal:{size}:{w.hexdigest()}" if size else sig


def _sizes(sig: dict) -> dict:
    """An outputs' signature with the large files' (size, time) as their size: a new time alone (a backup restored,
    rsync without -t, touch) is no edit, and re-making a 4 GB DOM or a classified strip for it costs hours
    (review 41)."""
    return {k: v[0] if isinstance(v, list) else v for k, v in sig.items()}


def _plain(options: dict, root: Path | None = None) -> dict:
    """Options as they read back from the JSON stamp (tuples become lists, paths text); paths inside the project
    folder ``root`` relative to it, so a copied or moved project keeps its stages up to date."""
    out = json.loads(json.dumps(options, default=str))
    if root is None:
        return out
    prefixes = {str(Path(root)) + os.sep, str(Path(root).resolve()) + os.sep, os.path.abspath(root) + os.sep}

    def rel(v):
        if isinstance(v, dict):
            return {k: rel(x) for k, x in v.items()}
        if isinstance(v, list):
            return [rel(x) for x in v]
        if isinstance(v, str):
            for prefix in prefixes:
                if v.startswith(prefix):
                    return v[len(prefix):]
        return v

    return rel(out)


def stamp_path(root: Path, stage: str) -> Path:
    return project_paths(root).stages_dir / f"{stage}.json"


def is_current(root: Path, st: Stage) -> bool:
    return stale_reason(root, st) is None


def _resume_dir(root: Path, stage: str) -> Path:
    """Where the stage keeps what an interrupted run of it finished (``work/<stage>_resume``)."""
    return project_paths(root).work_dir / f"{stage}_resume"


def stale_reason(root: Path, st: Stage) -> str | None:
    """Why the stage must run (None: up to date): no stamp, an output missing, the inputs, the options or the
    algorithm versions that changed since its stamp (by name: a new key of a newer version's settings re-runs a stage
    too; a stamp without versions, written before they were recorded, runs again if the stage declares versions)."""
    sp = stamp_path(root, st.name)
    if not sp.exists():
        # (trial s96 L1: "not run before", then "resumed 4 of 4 tiles an interrupted run finished")
        if _resume_dir(root, st.name).is_dir():
            return "not finished before: an interrupted run's finished parts are taken over"
        return "not run before"
    try:
        stamp = json.loads(sp.read_text())
    except json.JSONDecodeError:
        return f"{_key(sp, root)} unreadable"
    outputs = st.outputs(root)
    missing = [_key(p, root) for p in outputs if not p.exists()]
    if missing:
        return f"output missing: {_names(missing)}"
    gone = st.listed_missing(root) if st.listed_missing is not None else None
    if gone:
        return gone
    reasons = []
    # an output written since by another command (aerotri adjust or ortho mosaic by hand) or edited (at/eo.txt):
    # the stamp's numbers no longer describe it and the later stages would build on what project.toml does not
    # say; a fresh project would have this stage's own output
    if "outputs" in stamp:
        before = stamp["outputs"] or {}
        changed = _differing(_sizes(before), _sizes(_signature(outputs, root, before=before)))
    else:
        # a stamp written before outputs were recorded (before trial-rerun): an output newer than the stamp was
        # written after the stage (the stage writes its stamp last). Review 44: such a stamp found up to date has
        # its outputs recorded (``_refresh_stamp``), which blessed a hand edit made before (at/eo.txt X +5 m)
        # Review 47: a copy without times (cp -r) makes every output newer, and re-ran 7 of 11 demo stages (hours on a
        # block) for no edit ("a new time alone is no edit", review 41): said, taken as the stage's, not re-run
        stamped_ns = sp.stat().st_mtime_ns
        newer = _names([_key(p, root) for p in outputs if p.stat().st_mtime_ns > stamped_ns])
        if newer:
            _log.warning(f"[{st.name}] {newer} newer than this stage's record, which (written before outputs were "
                         "recorded) cannot tell an edit from a copy without times (cp -r; cp -a and rsync -t keep "
                         "them): taken as the stage's own; `aerotri run --force` makes every stage again")
        changed = None
    kept_note = None
    if changed:
        kept = st.hand_made(root) if changed and st.hand_made is not None else None
        if kept:
            kept_note = (f"[{st.name}] kept: {changed} changed since this stage wrote it ({kept}); the chain makes "
                         "its own again once it is removed")
        elif changed:
            reasons.append(f"outputs changed since this stage wrote them: {changed}")
    before = stamp.get("inputs") or {}
    inputs = _differing(before, _signature(st.inputs(root), root, before=before))
    if inputs:
        reasons.append(f"inputs changed: {inputs}")
    options = _differing(stamp.get("options") or {}, _plain(st.options_now(root), root), values=True)
    if options:
        reasons.append(f"options changed: {options}")
    now = st.versions_now()
    if "versions" not in stamp:
        # written before versions were recorded: which code made its outputs is unknown (an old project kept
        # outputs of rules since replaced for ever), so a stage that declares versions runs again
        if now:
            reasons.append("code versions not recorded: run again")
    else:
        versions = _differing(stamp["versions"] or {}, now, values=True)
        if versions:
            reasons.append(f"code changed: {versions}")
    if kept_note and not reasons:
        # said only when the stage stays as the user left it: a stage that runs for another reason says how it
        # treats the user's output itself (trial s106 F3: "kept" then "made again with the edited seamlines")
        _log.warning(kept_note)
    return "; ".join(reasons) or None


def _names(names: list[str], at_most: int = 4) -> str:
    more = f" and {len(names) - at_most} more" if len(names) > at_most else ""
    return ", ".join(names[:at_most]) + more


def _differing(before: dict, now: dict, values: bool = False) -> str:
    """What differs between a stamp's record and now, in one wording for inputs, options and code versions:
    ``a (new)``, ``b (dropped)``, nested keys dotted (``surface.b``), a changed value as ``k 1 -> 2`` when ``values``
    and both are short plain values (input hashes are not worth reading: their names only); at most four named."""
    return _names(_differing_keys(before, now, "", values))


def _short(v) -> bool:
    return v is None or isinstance(v, (bool, int, float)) or (isinstance(v, str) and len(v) <= 24)


def _differing_keys(before: dict, now: dict, prefix: str, values: bool) -> list[str]:
    out = []
    for k in sorted(set(before) | set(now), key=str):
        name = f"{prefix}{k}"
        if k not in before:
            out.append(f"{name} (new)")
        elif k not in now:
            out.append(f"{name} (dropped)")
        elif isinstance(before[k], dict) and isinstance(now[k], dict):
            out += _differing_keys(before[k], now[k], f"{name}.", values)
        elif isinstance(before[k], list) and isinstance(now[k], list) and len(before[k]) == len(now[k]) and \
                all(isinstance(a, dict) and isinstance(b, dict) for a, b in zip(before[k], now[k])):
            for i, (a, b) in enumerate(zip(before[k], now[k])):
                out += _differing_keys(a, b, f"{name}[{i}].", values)
        elif before[k] != now[k]:
            shown = values and _short(before[k]) and _short(now[k])
            out.append(f"{name} {json.dumps(before[k])} -> {json.dumps(now[k])}" if shown else name)
    return out


def run_stages(root, stages: list[Stage], force: bool = False, log: Callable[[str], None] = _log.info) -> list[dict]:
    """Run (or skip) the stages in order; returns one summary row per stage."""
    root = Path(root)
    rows = []
    load_start = _load_avg()
    summary_path = project_paths(root).run_summary_path
    # an earlier run's summary would describe this run if it stops: a run killed (-9) leaves none (bench/scale.py
    # then reads the stamps of the stages that finished), a failed or interrupted one its rows so far and the
    # stage that stopped (trial-overnight: a run that failed at rectify left the last run's "rectify done")
    summary_path.unlink(missing_ok=True)
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    clock = {}  # when the stage under way began (perf_counter): a stopped stage's row gets its seconds
    if any(st.name == "report" for st in stages):
        # the report of the run before says, until this run's report stage, that a run is under way: one killed
        # (SIGKILL: the out-of-memory killer) left last night's "pass" unmarked (trial s96 M1)
        _mark_report(root, f"a run started at {started} and has not ended (still running, or killed: SIGKILL, out "
                           "of memory, a power cut)", lambda m: _log.debug(m), running=True)
    try:
        _run_each(root, stages, rows, force, log, clock)
    except BaseException as exc:
        stopped = "interrupted" if interrupt_of(exc) is not None else "failed"
        done_names = {r["stage"] for r in rows}
        stage = next((st.name for st in stages if st.name not in done_names), None)
        if stage is not None:
            # (trial s96 L2: 0.0 s for a stage stopped after 11 s)
            seconds = round(time.perf_counter() - clock["t0"], 1) if "t0" in clock else 0.0
            rows.append(dict(stage=stage, status=stopped, seconds=seconds, why=str(exc) or type(exc).__name__))
        try:
            write_text_atomic(summary_path, json.dumps(dict(stages=rows, stopped=stopped, load_avg_start=load_start,
                                                            load_avg_end=_load_avg()), indent=1, default=str) + "\n")
        except OSError:  # (a full disk: no summary rather than the last run's)
            pass
        reported = any(r["stage"] == "report" and r["status"] in ("done", "skipped (up to date)") for r in rows)
        if stage is not None and not reported and any(st.name == "report" for st in stages):
            _mark_stopped_run(root, exc, f"the run of {started} stopped at {stage}", log)
        raise
    write_text_atomic(summary_path, json.dumps(
        dict(stages=rows, load_avg_start=load_start, load_avg_end=_load_avg()), indent=1, default=str) + "\n")
    return rows


def _mark_stopped_run(root, exc: BaseException, stopped_at: str, log: Callable[[str], None] = _log.info) -> None:
    """Mark the earlier run's report stale (``_mark_report``) for a run that ``exc`` stopped in a stage (``stopped_at``:
    "the run of <time> stopped at <stage>"), saying why as the console's error does; a failure of the marking is
    warned, never raised over ``exc``. (A refusal before the first stage marks nothing: bad input changes no file.)"""
    from aerotri.core.commands import fault_message

    interrupt = interrupt_of(exc)
    stopped = "interrupted" if interrupt is not None else "failed"
    try:
        if interrupt is not None:
            why = str(interrupt) or "Ctrl-C"
        else:  # what the console's error says (a full disk names the file), without what the banner says itself
            why = (fault_message(exc, "aerotri run") or "").split("; ")[0] or \
                (str(exc).splitlines() or [type(exc).__name__])[0]
        _mark_report(root, f"{stopped_at} ({stopped}: {why})", log)
    except Exception as e:  # (the error that stopped the run is what the console must say, not this one's)
        _log.warning(f"[report] the earlier run's report is not marked stale: {e}")


def _mark_report(root: Path, note: str, log: Callable[[str], None], running: bool = False) -> None:
    """(``run_stages``, a run that stopped before its report stage made a report) mark the earlier run's report stale
    (``aerotri.qa.report.mark_report_stale``), so that its QA reader is not shown the last good run as this one;
    ``running``: the mark of a run under way."""
    from aerotri.qa.report import mark_report_stale

    try:
        marked, failed = mark_report_stale(root, note, running=running)
    except Exception as exc:  # (a project unreadable now: the console and the exit code say what stopped the run)
        marked, failed = [], [f"{root}: {exc}"]
    if marked:
        log(f"[report] {', '.join(_key(p, root) for p in marked)} marked stale: {note}")
    for f in failed:  # (a disk still full): said, so that the reader of the console knows the report is the old one
        _log.warning(f"[report] the earlier run's report is not marked stale: {f}")


def _run_each(root: Path, stages: list[Stage], rows: list[dict], force: bool, log: Callable[[str], None],
              clock: dict | None = None) -> None:
    """(``run_stages``) each stage in turn, its summary row appended to ``rows``; ``clock["t0"]``: when the stage
    under way began."""
    clock = {} if clock is None else clock
    pending = _ForcePending(root, [st.name for st in stages] if force else None)
    for k, st in enumerate(stages, 1):
        clock["t0"] = time.perf_counter()
        if st.name == "report":  # the report as its stage wrote it before it is judged up to date (run_stages' mark)
            from aerotri.qa.report import clear_running_mark

            clear_running_mark(root)
        reason = st.skip(root) if st.skip is not None else None
        if reason:
            rows.append(dict(stage=st.name, status="skipped", seconds=0.0, why=reason))
            log(f"[{st.name}] skipped: {reason}")
            pending.done(st.name)
            continue
        why = "--force" if force else stale_reason(root, st) or pending.reason(st.name)
        if why is None:
            stamp = json.loads(stamp_path(root, st.name).read_text())
            _refresh_stamp(root, st, stamp)
            # the seconds of the run that made it kept beside (trial s96 L3: a night with nothing to do wrote 0.0 s
            # for every stage over the timings of the run that did the work)
            rows.append(dict(stage=st.name, status="skipped (up to date)", seconds=0.0, **stamp.get("result", {}),
                             **({"seconds_when_run": stamp["seconds"]} if "seconds" in stamp else {})))
            log(f"[{st.name}] up to date, skipped")
            # what an interrupted run of it (--force) had finished is of no use beside current outputs (trial s96
            # L5: work/control_resume stayed through two more runs)
            leftover = _resume_dir(root, st.name)
            if leftover.is_dir():
                shutil.rmtree(leftover, ignore_errors=True)
            continue
        log(f"[{st.name}] running ({why})")
        _remove_stale_temporaries(st.outputs(root))
        options = _plain(st.options_now(root), root)  # before the run: the stage may change what they depend on
        versions = st.versions_now()
        # the stage's outputs and its stamp are one commit: all new, or (an error, a kill) all as before;
        # a separate commit, final when the stage ends, so that a killed run resumes after its last stage
        with doing(st.name), commit_outputs(root, join=False):
            with measure() as usage:
                done = st.run(root)
            result = done.record()
            dt = usage.wall_s
            missing = [str(p) for p in st.outputs(root) if not p.exists()]
            if missing:
                raise RuntimeError(f"stage {st.name} finished without writing {', '.join(missing)}")
            write_text_atomic(stamp_path(root, st.name), json.dumps(
                dict(inputs=_signature(st.inputs(root), root), outputs=_signature(st.outputs(root), root),
                     options=options, versions=versions, result=result, seconds=round(dt, 2),
                     usage=usage.record()), indent=1, default=str) + "\n")
        rows.append(dict(stage=st.name, status="skipped" if done.why else "done", seconds=round(dt, 1),
                         **_usage_columns(usage.record()), **result))
        for note in done.notes:
            log(f"[{st.name}] note: {note}")
        if done.why:
            log(f"[{st.name}] skipped: {done.why}")
        log(f"[{st.name}] done in {dt:.1f} s (stage {k} of {len(stages)})")  # (trial s96 L10: no stage counter)
        pending.done(st.name)
        if memory_limited():
            # under a container's or batch job's limit the memory a stage freed goes back to the system, not kept by
            # the allocator for the next stage (the demo at 1 GiB: killed in its lidar_eval stage, 12th of 15)
            release_freed_memory()


class _ForcePending:
    """The stages a ``--force`` run has not re-run yet, in ``work/force_pending.json`` until it ends: a run stopped
    midway (a kill, Ctrl-C, a failure) leaves them there, and the next run without ``--force`` re-runs them as well
    (trial s96 L11: it found them "up to date", the operator had to remember to repeat --force)."""

    def __init__(self, root: Path, forced: list[str] | None):
        self.path = project_paths(root).work_dir / "force_pending.json"
        if forced is not None:
            self.started, self.stages = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), list(forced)
            self._write()
            return
        try:
            record = json.loads(self.path.read_text())
            self.started, self.stages = str(record["started"]), [str(x) for x in record["stages"]]
        except (OSError, ValueError, KeyError, TypeError):  # none (the usual case), or unreadable: nothing pending
            self.started, self.stages = "", []

    def reason(self, stage: str) -> str | None:
        if stage in self.stages:
            return f"the --force run of {self.started} stopped before re-running it"
        return None

    def done(self, stage: str) -> None:
        if stage in self.stages:
            self.stages.remove(stage)
            self._write()

    def _write(self) -> None:
        if self.stages:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            write_text_atomic(self.path, json.dumps(dict(started=self.started, stages=self.stages)) + "\n")
        else:
            self.path.unlink(missing_ok=True)


def _refresh_stamp(root: Path, st: Stage, stamp: dict) -> None:
    """Bring the stamp of an up-to-date stage to what stamps record now, without running it (its outputs are the
    stage's as far as the chain knows): the outputs' signatures when it was written before they were recorded (before
    trial-rerun; leftovers2: such a stamp was skipped run after run with its outputs never recorded, so a later edit of
    them was never seen), and a SQLite file's ``_sqlite_hash`` for its plain hash (a stamp of before leftovers2: a
    reader's touch would re-run the stage once)."""
    changed = "outputs" not in stamp
    if changed:
        stamp["outputs"] = _signature(st.outputs(root), root)
    for record in (stamp.get("inputs") or {}, stamp["outputs"] or {}):
        for name, value in record.items():
            path = Path(root) / name  # (a name outside the project is absolute)
            if value is not None and not str(value).startswith(_SQLITE_PREFIX) and _is_sqlite(path):
                record[name] = _sqlite_hash(path)
                changed = True
    if changed:
        write_text_atomic(stamp_path(root, st.name), json.dumps(stamp, indent=1, default=str) + "\n")


_USAGE_COLUMNS = ("cpu_s", "peak_rss_mb", "workers_peak_rss_mb")


def _usage_columns(record: dict) -> dict:
    """The stage-cost numbers a summary row carries (wall time is its ``seconds``)."""
    return {k: record[k] for k in _USAGE_COLUMNS if k in record}


def _load_avg() -> list[float] | None:
    """1, 5 and 15 minute load averages (None where the system has none)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def _remove_stale_temporaries(outputs: list[Path]) -> None:
    """Delete what a killed earlier attempt left of its atomic writes in the folders of the stage's
    outputs (``aerotri.core.atomic.remove_leftovers``: the frame files next to ortho/frames/index.json, the
    mosaic's and the rasters' work folders, the LiDAR tiles' work folder, ...)."""
    for folder in sorted({p.parent for p in outputs}):
        remove_leftovers(folder)


def format_summary(rows: list[dict]) -> str:
    """The table of stages: status, wall and CPU time, peak RSS (the process plus its workers) and key
    numbers; skipped stages say why, notes follow."""
    lines = [f"{'stage':<18} {'status':<22} {'time s':>7} {'CPU s':>7} {'peak MB':>8}  key numbers"]
    notes = []
    for r in rows:
        extra = "  ".join(f"{k}={_fmt(v)}" for k, v in r.items()
                          if k not in ("stage", "status", "seconds", "why", "notes") + _USAGE_COLUMNS)
        if r.get("why"):
            extra = r["why"]
        cpu = f"{r['cpu_s']:>7.1f}" if "cpu_s" in r else f"{'-':>7}"
        peak = r.get("peak_rss_mb", 0.0) + r.get("workers_peak_rss_mb", 0.0)
        peak = f"{peak:>8.0f}" if "peak_rss_mb" in r else f"{'-':>8}"
        lines.append(f"{r['stage']:<18} {r['status']:<22} {r['seconds']:>7.1f} {cpu} {peak}  {extra}".rstrip())
        notes += [f"{r['stage']}: {n}" for n in r.get("notes", [])]
    if notes:
        lines += ["", "notes:"] + [f"  {n}" for n in notes]
    return "\n".join(lines)


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)
