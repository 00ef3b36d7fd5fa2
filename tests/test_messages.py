"""The message channel (app/core/messages.py): levels, one at a time from many threads, and what a
background solve adds reaching the viewer and the CLI after the session opened."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

from app.cli import main
from app.core.messages import ERROR, INFO, WARNING, Messages
from app.simulate.sample import SAMPLE_DIR
from app.ui.viewer import Options, Viewer


def test_levels_and_how_they_read():
    m = Messages()
    m.info("lens: pinhole")
    m.add("5 GNSS fixes dropped")
    m.error("offline: failed")
    assert [str(x) for x in m.since(0)] == [
        "note: lens: pinhole",
        "warning: 5 GNSS fixes dropped",
        "error: offline: failed",
    ]
    assert (
        m.of(WARNING) == ["5 GNSS fixes dropped"]
        and m.of(INFO) == ["lens: pinhole"]
        and m.of(ERROR) == ["offline: failed"]
    )
    m.add_once("k", "once")
    m.add_once("k", "twice")
    assert m.items[-1] == "once" and len(m) == 4
    with pytest.raises(ValueError, match="level"):
        m.add("x", "loud")


def test_many_threads_add_without_losing_one():
    m = Messages()

    def work(i: int) -> None:
        for j in range(500):
            m.add(f"{i}-{j}")
            m.add_once(f"key{j}", f"once {j}")

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(m) == 8 * 500 + 500
    assert len(set(m.items)) == len(m)


def test_what_a_background_solve_says_reaches_the_viewer_after_open():
    """The viewer shows each message as it comes, by level, not a copy taken at open."""
    messages = Messages()
    v = Viewer(Options(None))
    v.loaded = SimpleNamespace(session=SimpleNamespace(messages=messages))
    messages.info("lens: pinhole")
    v._show_messages()
    added = threading.Thread(
        target=lambda: (
            messages.add("3 GNSS fixes lie off the model"),
            messages.error("registered: failed"),
        )
    )
    added.start()
    added.join()
    v._show_messages()
    v._show_messages()  # nothing new: nothing repeated
    assert v.ui.info == ["lens: pinhole"]
    assert v.ui.warnings == ["3 GNSS fixes lie off the model"]
    assert v.ui.errors == ["registered: failed"]


def test_the_cli_prints_each_message_with_its_level(tmp_path, capsys):
    assert (
        main(
            [
                "solve",
                str(SAMPLE_DIR / "session.toml"),
                "--source",
                "gd-ahrs",
                "--out",
                str(tmp_path / "p.csv"),
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "note: magnetometer calibrated on the clip" in err
    assert "warning: rolling shutter: readout time unknown" in err
    assert "warning: magnetometer calibrated" not in err
