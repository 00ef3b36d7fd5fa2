"""Every case of the damaged-input corpus (tests/corpus/table.py) through the CLI: exit 0 or 2 as
the table says, never a traceback, one line naming the file, key or option for exit 2, a warning
wherever data were dropped, no input changed (hashes before and after), no NaN in any output."""

from __future__ import annotations

import csv
import hashlib
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from tests.conftest import SHARED_DATA
from tests.corpus import generate
from tests.corpus.table import CASES

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def clean_session(tmp_path_factory) -> Path:
    return generate.phone_session(tmp_path_factory.mktemp("corpus-clean") / "session").parent


def _hashes(folder: Path) -> dict[Path, str]:
    return {
        p: hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _outputs(case_dir: Path, before: dict[Path, str]) -> list[Path]:
    return [p for p in case_dir.rglob("*") if p.is_file() and p not in before]


def _no_nan(path: Path) -> None:
    if path.suffix == ".geojson":
        import json

        json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"{path}: {c} in JSON"))
    elif path.suffix == ".csv":
        with path.open() as f:
            rows = list(csv.reader(f))
        cells = [c for r in rows[1:] for c in r]
        assert cells and not any(c.strip().lower() in ("nan", "inf", "-inf") for c in cells), path
    elif path.suffix == ".png":
        from PIL import Image

        img = np.asarray(Image.open(path))
        assert img.size and img.std() > 0, path


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_corpus_case(case, clean_session, tmp_path, capsys, request):
    if case.shared:
        request.getfixturevalue("shared_data")
    d = tmp_path / "case"
    generate.copy_session(clean_session, d / "session")
    make = getattr(generate, case.make)
    make(d, SHARED_DATA) if case.shared else make(d)
    shared_before = {}
    argv = [a.format(d=d, s=d / "session" / "session.toml", shared=SHARED_DATA) for a in case.argv]
    before = _hashes(d)
    if case.shared:
        shared_before = _hashes(SHARED_DATA / "real")
    code = main(argv)
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    if case.outcome in ("ok", "nothing drawn"):
        assert code == (0 if case.outcome == "ok" else 1), out.err
        if case.outcome == "nothing drawn":
            assert "nothing of the scene was drawn" in out.err, out.err
        if case.says:
            assert case.says in out.err + out.out, out.err
        for p in _outputs(d, before):
            _no_nan(p)
    else:
        assert code == 2, (code, out.err)
        lines = out.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("geofuse: error: "), out.err
        assert case.says in lines[0], lines[0]
    after = _hashes(d)
    assert {p: h for p, h in after.items() if p in before} == before  # no input changed
    if case.shared:
        assert _hashes(SHARED_DATA / "real") == shared_before
