"""`geofuse` command line. parser.py defines every command's options (and imports nothing
heavy); each command's work lives in its own module here (render.py, export.py, sync.py, ...),
which imports what it needs at its top and calls the modules that own the work.

The one lazy import of the command line is here: the command's module is imported after the
arguments are parsed, so that `geofuse --help` and `geofuse telemetry FILE` load neither numba
nor OpenGL (tests/test_imports.py; the import times are in docs/ARCHITECTURE.md).

Every GeofuseError (bad file, bad value) is printed as one line naming the file and field, and
the command exits with status 2; no traceback.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

from app.cli.parser import build_parser, joined_negative_values
from app.core.errors import GeofuseError

__all__ = ["build_parser", "main"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(joined_negative_values(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:  # --help, or an argument error already printed as one line
        return int(exc.code or 0)
    module, _, function = args.job.partition(":")
    job = getattr(importlib.import_module(f"app.cli.{module}"), function or "run")
    try:
        return int(job(args))
    except GeofuseError as exc:
        print(f"geofuse: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system said no (a folder, no permission, a full disk)
        print(f"geofuse: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2
