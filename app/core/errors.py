"""Domain error types. Each names the file and, where known, the line or field at fault."""

from __future__ import annotations

from pathlib import Path


class GeofuseError(Exception):
    """Base class of every error geofuse reports to a person (CLI exit status 2, viewer panel)."""


class DataFormatError(GeofuseError):
    """A file that cannot be read as expected.

    The message reads ``FILE[:LINE][ field FIELD]: what is wrong (expected ...)``.
    """

    def __init__(
        self,
        path: str | Path,
        message: str,
        *,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = Path(path)
        self.line = line
        self.field = field
        self.detail = message
        text = str(path)
        where = text if "://" in text else str(self.path)  # a URL keeps its "//" (Path folds it)
        if line is not None:
            where += f":{line}"
        if field is not None:
            where += f" field {field!r}"
        super().__init__(f"{where}: {message}")


class SceneError(DataFormatError):
    """A scene file that is missing, of an unknown format, or holds no drawable faces."""


class VideoError(DataFormatError):
    """A video that cannot be opened or decoded."""


class ManifestError(DataFormatError):
    """A session manifest with a missing or invalid key (``field`` names the key)."""


class ShaderError(GeofuseError):
    """A GLSL source that fails to preprocess or compile; the message points at file:line."""
