"""Where a frame's time goes, pass by pass: the CPU's wall time of each named section of a frame
and the GPU's own time for the commands it issued (a GL_TIME_ELAPSED query per section).

For benchmarks and profiling (bench/bench_render.py): a FusionRenderer with a timer set wraps
its passes in `section(name)`; without one it costs nothing. Timer queries cannot nest, so the
sections of one frame follow one another. The GPU's times are read at `end_frame`, after the
frame was finished (reading a query waits for the GPU).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import moderngl


class PassTimer:
    """Per-section times of the frames drawn while it is set: `cpu_s[name]` and `gpu_s[name]`,
    one entry per frame that ran the section (seconds)."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self._queries: dict[str, moderngl.Query] = {}
        self._pending: list[str] = []
        self.cpu_s: dict[str, list[float]] = {}
        self.gpu_s: dict[str, list[float]] = {}

    @contextmanager
    def section(self, name: str) -> Iterator[None]:
        """Time the block as section `name` of the current frame."""
        query = self._queries.get(name)
        if query is None:
            query = self._queries[name] = self.ctx.query(time=True)
        t0 = time.perf_counter()
        with query:
            yield
        self.cpu_s.setdefault(name, []).append(time.perf_counter() - t0)
        self._pending.append(name)

    def end_frame(self) -> None:
        """Read the GPU's times of the frame's sections (call after ctx.finish())."""
        for name in self._pending:
            self.gpu_s.setdefault(name, []).append(self._queries[name].elapsed / 1e9)
        self._pending.clear()

    def clear(self) -> None:
        """Forget the times taken so far (the queries are kept)."""
        self.cpu_s.clear()
        self.gpu_s.clear()
        self._pending.clear()
