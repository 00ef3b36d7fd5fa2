"""GLSL files from shaders/: `#include "file.glsl"` resolution and `#line` bookkeeping.

Pure text processing (no GL), so it is testable without a context. Each source file gets a
numeric id; the preprocessed text carries `#line LINE ID` directives so that a compiler message
such as `0:12(5): error` maps back to `include/projective.glsl:12`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from app.core.errors import ShaderError

SHADER_DIR = Path(__file__).resolve().parents[2] / "shaders"
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$')
_VERSION = re.compile(r"^\s*#\s*version\b")
# Mesa: "0:12(5): error: ...", NVIDIA: "0(12) : error ...".
_MESSAGE = re.compile(r"(?P<id>\d+)(?::(?P<line1>\d+)\(\d+\)|\((?P<line2>\d+)\))")


@dataclass
class ShaderSource:
    """Preprocessed GLSL text and the file behind each `#line` source id."""

    text: str
    files: list[str] = field(default_factory=list)

    def locate(self, message: str) -> str:
        """Rewrite `ID:LINE(COL)` / `ID(LINE)` references in a compiler log as `file:LINE`."""

        def sub(m: re.Match[str]) -> str:
            sid = int(m.group("id"))
            line = m.group("line1") or m.group("line2")
            name = self.files[sid] if sid < len(self.files) else f"source {sid}"
            return f"{name}:{line}"

        return _MESSAGE.sub(sub, message)


def preprocess(
    name: str, root: Path = SHADER_DIR, defines: dict[str, int] | None = None
) -> ShaderSource:
    """Read shaders/NAME and inline its includes (looked up in shaders/include/, then shaders/).

    defines: `#define NAME VALUE` lines put after the version directive (a specialised variant
    of the shader; the file's own `#ifndef` defaults stand for the rest)."""
    files: list[str] = []
    out: list[str] = []

    def find(include: str, parent: Path) -> Path:
        for base in (root / "include", parent, root):
            candidate = base / include
            if candidate.is_file():
                return candidate
        raise ShaderError(
            f"{parent.relative_to(root) if parent != root else '.'}: include {include!r} not found"
        )

    def emit(path: Path, stack: tuple[Path, ...]) -> None:
        if path in stack:
            chain = " -> ".join(p.name for p in (*stack, path))
            raise ShaderError(f"{path.relative_to(root)}: circular include ({chain})")
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise ShaderError(f"{path}: cannot read shader ({exc})") from exc
        sid = len(files)
        files.append(str(path.relative_to(root)))
        for number, line in enumerate(lines, start=1):
            m = _INCLUDE.match(line)
            if m:
                emit(find(m.group(1), path.parent), (*stack, path))
                out.append(f"#line {number + 1} {sid}")
            elif _VERSION.match(line):
                if stack or number != 1 and any(s.strip() for s in lines[: number - 1]):
                    raise ShaderError(
                        f"{path.relative_to(root)}:{number}: the version directive must be the first line of the main file"
                    )
                out.append(line)
                if not stack:
                    out.extend(f"#define {k} {int(v)}" for k, v in sorted((defines or {}).items()))
                out.append(f"#line {number + 1} {sid}")
            else:
                out.append(line)

    main = root / name
    if not main.is_file():
        raise ShaderError(f"shader {name!r} not found in {root}")
    emit(main, ())
    return ShaderSource("\n".join(out) + "\n", files)
