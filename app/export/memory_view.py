"""What the viewer shows of a surface memory (app.export.memory): a colour per sample for each
view, as the memory was at a moment of the timeline. Pure numpy.

Views:
- model: the model's own colour (the memory is not drawn).
- memory: the painted colour where the sample had been seen by `at_s`, else the model's own.
- seen: when each sample was seen, on a ramp from blue (the memory's earliest sighting) through
  green and yellow to red (`at_s`, or the latest); samples not seen show the model's own colour
  in grey, dimmed.
- changed: how far the painted colour is from the model's own, once one gain and offset per
  channel and per face, fitted over the samples seen, has taken out the camera's exposure, white
  balance and the day's light on that face (those are not a change): the model in grey, red laid
  over it in proportion to the difference (full at CHANGE_FULL, an RGB distance).

"As it was at at_s" (seconds on the memory's clock, the viewer's timeline): a sample whose kept
sighting (memory.time) is not after at_s shows it (exact: for the newest rule it was the last);
else, under the newest or best rule, the newest sighting of its history (app.export.memory) not
after at_s: exact to one epoch (a sighting earlier in at_s's own epoch, whose newest came after
at_s, is not kept; the epoch before's newest shows). Under the first rule the kept sighting is
exact whatever at_s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.export.memory import SurfaceMemory

VIEWS = ("model", "memory", "seen", "changed")
MIN_GROUP = 16  # seen samples a group needs for a fit of its own (change)
CHANGE_FULL = 96.0  # an RGB distance (0..441) that the changed view shows fully red
RAMP = np.array(  # the "seen at" ramp: old to new
    [(0.0, 40, 60, 200), (0.35, 30, 170, 220), (0.6, 60, 200, 70), (0.8, 240, 210, 40), (1.0, 220, 30, 30)]
)  # fmt: skip


@dataclass(frozen=True)
class Snapshot:
    """The memory as it was at a moment: rgb (N, 3) uint8, seen (N,) bool, time (N,) float64 s
    (NaN where not seen)."""

    rgb: np.ndarray
    seen: np.ndarray
    time: np.ndarray


def as_at(memory: SurfaceMemory, at_s: float | None) -> Snapshot:
    """The memory as it was at at_s (None: as it is); see the module docstring."""
    if at_s is None:
        return Snapshot(memory.rgb, memory.seen, memory.time)
    with np.errstate(invalid="ignore"):
        kept = memory.seen & (memory.time <= at_s)
    rgb = memory.rgb.copy()
    time = np.where(kept, memory.time, np.nan)
    if memory.history is None or memory.rule == "first":
        return Snapshot(rgb, kept, time)
    times = memory.epoch_starts()[None, :] + memory.history_dt  # (N, E), NaN none
    with np.errstate(invalid="ignore"):
        valid = times <= at_s
    last = valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1)  # the newest valid epoch
    older = ~kept & valid.any(axis=1)
    rows = np.flatnonzero(older)
    rgb[rows] = memory.history_rgb[rows, last[rows]]
    time[rows] = times[rows, last[rows]]
    return Snapshot(rgb, kept | older, time)


def ramp(x: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours of x (N,) in [0, 1] on the "seen at" ramp (blue old, red new)."""
    x = np.clip(np.nan_to_num(np.asarray(x, np.float64)), 0.0, 1.0)
    return np.stack([np.interp(x, RAMP[:, 0], RAMP[:, c]) for c in (1, 2, 3)], axis=1).astype(
        np.uint8
    )


def grey(base: np.ndarray, dim: float = 0.75) -> np.ndarray:
    """(N, 3) uint8: the colours' luminance (Rec. 601), times dim."""
    y = base.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.repeat(np.clip(y * dim, 0, 255).astype(np.uint8)[:, None], 3, axis=1)


def seen_range(snapshot: Snapshot) -> tuple[float, float] | None:
    """(earliest, latest) sighting shown, s; None when nothing is seen."""
    if not snapshot.seen.any():
        return None
    t = snapshot.time[snapshot.seen]
    return float(t.min()), float(t.max())


def change(snapshot: Snapshot, base: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
    """(N,) RGB distance (0..441) between the painted colour and the model's own once one gain
    and offset per channel and per group (groups (N,) int, e.g. the samples' triangles: a face's
    own light; None: one group) has been fitted over the seen samples (least squares, painted
    from model); 0 where not seen. A group with under MIN_GROUP seen samples takes the fit of
    all of them."""
    out = np.zeros(len(base), np.float32)
    s = np.flatnonzero(snapshot.seen)
    if len(s) < 2:
        return out
    y = snapshot.rgb[s].astype(np.float64)
    x = base[s].astype(np.float64)
    g = np.zeros(len(s), np.int64) if groups is None else np.asarray(groups)[s]
    _, g = np.unique(g, return_inverse=True)
    n = np.bincount(g).astype(np.float64)
    small = n[g] < MIN_GROUP
    fitted = np.empty_like(y)
    for c in range(3):
        a, b = _fit(x[:, c], y[:, c], g, len(n))
        a_all, b_all = _fit(x[:, c], y[:, c], np.zeros(len(s), np.int64), 1)
        fitted[:, c] = np.where(small, a_all[0] * x[:, c] + b_all[0], a[g] * x[:, c] + b[g])
    out[s] = np.linalg.norm(y - fitted, axis=1)
    return out


def _fit(x: np.ndarray, y: np.ndarray, g: np.ndarray, groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Per group, the gain and offset of y on x (least squares); a group whose x does not vary
    gets gain 0 and y's mean."""
    n = np.bincount(g, minlength=groups).astype(np.float64)
    sx, sy = np.bincount(g, x, groups), np.bincount(g, y, groups)
    sxx, sxy = np.bincount(g, x * x, groups), np.bincount(g, x * y, groups)
    var = n * sxx - sx * sx
    flat = var <= 1e-6 * np.maximum(n * n, 1.0)
    gain = np.where(flat, 0.0, (n * sxy - sx * sy) / np.where(flat, 1.0, var))
    return gain, (sy - gain * sx) / np.maximum(n, 1.0)


def view_colours(
    memory: SurfaceMemory,
    base: np.ndarray,
    view: str,
    at_s: float | None = None,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """(N, 3) uint8 per sample for `view` (VIEWS) of the memory as it was at at_s; base (N, 3)
    uint8 the model's own colours at the samples; groups (N,) int the faces the changed view
    fits the light of separately (see change)."""
    if view not in VIEWS:
        raise ValueError(f"view {view!r}: expected one of {', '.join(VIEWS)}")
    if view == "model":
        return base
    return snapshot_colours(as_at(memory, at_s), base, view, at_s, groups)


def snapshot_colours(
    snap: Snapshot,
    base: np.ndarray,
    view: str,
    at_s: float | None = None,
    groups: np.ndarray | None = None,
) -> np.ndarray:
    """view_colours of a snapshot already taken (as_at(memory, at_s)); view not model."""
    if view == "memory":
        return np.where(snap.seen[:, None], snap.rgb, base)
    out = grey(base)
    if view == "seen":
        span = seen_range(snap)
        if span is not None:
            t0, t1 = span[0], span[1] if at_s is None else max(at_s, span[1])
            x = (snap.time[snap.seen] - t0) / max(t1 - t0, 1e-9)
            out[snap.seen] = ramp(x)
        return out
    k = np.clip(change(snap, base, groups) / CHANGE_FULL, 0.0, 1.0)[:, None]
    red = np.array([230.0, 30.0, 30.0])
    return np.clip(np.round(out * (1.0 - k) + red * k), 0, 255).astype(np.uint8)
