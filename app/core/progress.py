"""A one-line progress bar for long commands, on stderr: label, bar, percent, time left."""

from __future__ import annotations

import time
from typing import TextIO

BAR_WIDTH = 30


def is_terminal(out: TextIO | None) -> bool:
    """Whether `out` is a terminal a person watches (a redirected log or a pipe is not)."""
    isatty = getattr(out, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # a closed stream
        return False


class ProgressBar:
    """Call with the fraction done (0..1); prints nothing when `out` is None or not a terminal
    (a redirected log gets no bar redrawn a hundred times)."""

    def __init__(self, label: str, out: TextIO | None, clock=time.monotonic) -> None:
        self.label, self.clock = label, clock
        self.out = out if is_terminal(out) else None
        self.start = clock()
        self._shown = -1.0

    def __call__(self, fraction: float) -> None:
        if self.out is None:
            return
        fraction = min(max(fraction, 0.0), 1.0)
        if fraction < 1.0 and fraction - self._shown < 0.01:
            return  # redraw every whole percent, not every frame
        self._shown = fraction
        filled = int(BAR_WIDTH * fraction)
        elapsed = self.clock() - self.start
        left = f"  {elapsed * (1 - fraction) / fraction:5.0f} s left" if 0 < fraction < 1 else ""
        self.out.write(
            f"\r{self.label:<28} [{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {100 * fraction:5.1f}%{left}"
        )
        if fraction >= 1.0:
            self.out.write("\n")
        self.out.flush()
