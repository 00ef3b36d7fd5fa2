"""Every file a command writes goes through here: the path is checked before any work is done (a
suffix the command can write, a parent folder that is or can be a folder, not a folder itself,
not one of the command's inputs), and the bytes are written to a temporary file beside it and then
renamed, so that a full disk or an unwritable place is a one-line error naming the file and the
option, and never leaves a half-written file or touches an input."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO

from app.core.errors import GeofuseError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
CSV_SUFFIXES = (".csv",)


class OutputError(GeofuseError):
    """An output path that cannot be written (the message names the option and the path)."""


def check_output(
    path: str | Path,
    option: str,
    suffixes: tuple[str, ...],
    inputs: Iterable[str | Path | None] = (),
) -> Path:
    """Validate an output path before the command works; returns it as a Path."""
    out = Path(path)
    if out.is_dir():
        raise OutputError(f"{option} {out}: is a folder, expected a file name")
    if out.suffix.lower() not in suffixes:
        raise OutputError(f"{option} {out}: expected a file ending in {' or '.join(suffixes)}")
    target = out.resolve()
    for p in inputs:
        if p and Path(p).exists() and Path(p).resolve() == target:
            raise OutputError(
                f"{option} {out}: is an input file of this command: refusing to overwrite it (choose another name)"
            )
    parent = target.parent
    existing = next((p for p in (parent, *parent.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise OutputError(f"{option} {out}: {existing} is a file, not a folder")
    if existing is not None and not os.access(existing, os.W_OK):
        raise OutputError(f"{option} {out}: cannot write in {existing} (permission denied)")
    return out


def write_atomically(
    path: Path, option: str, write: Callable[[IO], None], binary: bool = False
) -> Path:
    """Create the parent folder, write through `write(file)` to a temporary file beside `path`,
    then rename it over `path`. OSError (full disk, permissions) -> OutputError."""

    def through_file(tmp: Path) -> None:
        with tmp.open(
            "wb" if binary else "w", **({} if binary else {"newline": "", "encoding": "utf-8"})
        ) as f:
            write(f)

    return write_via_path(path, option, through_file)


def write_via_path(path: Path, option: str, write: Callable[[Path], None]) -> Path:
    """As write_atomically, for writers that open the file themselves: write(temporary path),
    where the temporary path keeps the output's suffix (muxers choose the format by it)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"{option} {path}: cannot create it ({exc.strerror or exc})") from exc
    try:
        write(Path(tmp))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(
            tmp, 0o666 & ~umask
        )  # mkstemp's 0600 is for the temporary file, not the user's output
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise OutputError(f"{option} {path}: writing failed ({exc.strerror or exc})") from exc
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
