"""Indexing an archive on Dask distributed: one task per clip, on a LocalCluster of processes
(each worker its own off-screen GL context) or on an existing cluster's scheduler.

Incremental: a clip whose path, size and modification time match a row of the clips table
already there keeps its rows and is not indexed again; a clip whose fingerprint matches one
indexed (in this run or before) is recorded as a duplicate of it and not indexed. A clip that
fails is recorded with its error; it never stops the others. A run after which the archive would
hold no indexed clip at all (no clip found, or every one failed) writes nothing and says why.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from dask.distributed import Client, LocalCluster, as_completed

from app.archive.clips import ClipResult, clip_key, fingerprint, index_clip, walk_clips
from app.archive.store import read_clips, write_archive
from app.core.errors import GeofuseError

__all__ = ["IndexReport", "index_archive"]


@dataclass(frozen=True)
class IndexReport:
    """found: clips under the roots; indexed, failed, duplicates, unchanged: how many of them;
    footprints: rows in the archive written; seconds: the run's wall time; failures: (clip,
    why) of each clip that failed in this run."""

    found: int
    indexed: int
    failed: int
    duplicates: int
    unchanged: int
    footprints: int
    seconds: float
    failures: tuple[tuple[str, str], ...] = ()

    def line(self) -> str:
        return (
            f"{self.found} clips: {self.indexed} indexed, {self.failed} failed, "
            f"{self.duplicates} duplicates, {self.unchanged} unchanged; "
            f"{self.footprints} footprints in the archive ({self.seconds:.1f} s)"
        )


FAILURES_SAID = 3  # the reasons of at most this many failed clips in the nothing-indexed error


def _nothing_indexed(
    roots: list[Path],
    archive: Path,
    clips: list[Path],
    passed_over: list[tuple[Path, str]],
    errors: list[str],
) -> GeofuseError:
    """The error of a run after which the archive would hold no indexed clip: what was found,
    why the clips failed (the first few; errors: this run's and those of unchanged clips that
    failed before) and what the other files were."""
    parts = [f"{len(clips)} clip(s) found" if clips else "no clip found"]
    if errors:
        reasons = "; ".join(" ".join(e.split()) for e in errors[:FAILURES_SAID])
        more = f"; and {len(errors) - FAILURES_SAID} more" if len(errors) > FAILURES_SAID else ""
        parts.append(f"{len(errors)} failed ({reasons}{more})")
    if len(errors) < len(clips):
        parts.append(f"{len(clips) - len(errors)} duplicate(s) of clips not in the archive")
    for why, n in sorted(Counter(why for _, why in passed_over).items()):
        parts.append(f"{n} file(s) skipped: {why}")
    where = ", ".join(str(r) for r in roots)
    return GeofuseError(f"{where}: nothing indexed: {'; '.join(parts)}; {archive} not written")


def _client(workers: int | None, scheduler: str | None) -> tuple[Client, LocalCluster | None]:
    if scheduler:
        return Client(scheduler), None
    cluster = LocalCluster(
        n_workers=workers or None,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
    )
    return Client(cluster), cluster


def index_archive(
    roots: list[Path],
    archive: Path,
    every_s: float = 1.0,
    scene: tuple[str, ...] = (),
    source: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int, int, float], None] | None = None,
) -> IndexReport:
    """Index the clips under `roots` into `archive` (see the module docstring). progress(done,
    failed, total, seconds left) after each clip."""
    started = time.perf_counter()
    clips, passed_over = walk_clips(roots)
    before = read_clips(archive)
    known = {
        row.path: (int(row.size), int(row.mtime_ns))
        for row in before.itertuples()
        if row.status in ("indexed", "duplicate", "failed")  # a damaged clip fails again
    }
    prints = {row.fingerprint: row.path for row in before.itertuples() if row.status == "indexed"}
    unchanged = [str(c) for c in clips if known.get(str(c)) == clip_key(c)]
    todo, results = [], []
    for c in clips:
        if str(c) in unchanged:
            continue
        fp = fingerprint(c)
        if fp in prints and prints[fp] != str(c):
            size, mtime = clip_key(c)
            results.append(
                ClipResult(str(c), size, mtime, fp, "duplicate", f"the same file as {prints[fp]}")
            )
            continue
        prints.setdefault(fp, str(c))
        todo.append((str(c), fp))
    if todo:
        client, cluster = _client(workers, scheduler)
        try:
            futures = [
                client.submit(index_clip, c, every_s, scene, source, fp, pure=False)
                for c, fp in todo
            ]
            done = failed = 0
            for future in as_completed(futures):
                result = future.result()
                results.append(result)
                done += 1
                failed += result.status == "failed"
                if progress is not None:
                    spent = time.perf_counter() - started
                    progress(done, failed, len(todo), spent / done * (len(todo) - done))
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    indexed = sum(r.status == "indexed" for r in results)
    kept = before[before["path"].isin(unchanged)]
    if indexed == 0 and not (kept["status"] == "indexed").any():
        errors = [r.error for r in results if r.status == "failed"]
        errors += list(kept.loc[kept["status"] == "failed", "error"])
        raise _nothing_indexed(roots, archive, clips, passed_over, errors)
    footprints, _ = write_archive(archive, results, unchanged)
    failures = tuple((r.path, r.error) for r in results if r.status == "failed")
    return IndexReport(
        len(clips),
        indexed,
        len(failures),
        sum(r.status == "duplicate" for r in results),
        len(unchanged),
        footprints,
        time.perf_counter() - started,
        failures,
    )
