"""app.core.worker.OneShot: a job run once on its own thread, its failure kept as one line for
the viewer (a GeofuseError's own text; anything else named with what failed and its type)."""

from __future__ import annotations

from app.core.errors import GeofuseError
from app.core.worker import OneShot


class _Job(OneShot):
    def __init__(self, raise_: Exception | None) -> None:
        self.raise_, self.result = raise_, None
        super().__init__("geofuse-test")

    def _work(self) -> None:
        if self.raise_ is not None:
            raise self.raise_
        self.result = 42

    def _failed(self) -> str:
        return "the test job"


def test_a_one_shot_job_keeps_its_result_or_its_failure_as_one_line():
    ok = _Job(None).start()
    assert ok.wait(10) and ok.done and ok.result == 42 and ok.error is None
    said = _Job(GeofuseError("clip.mp4: field 'x': expected y")).start()
    assert said.wait(10) and said.error == "clip.mp4: field 'x': expected y"
    odd = _Job(ValueError("boom"))
    odd.run()  # on the calling thread
    assert odd.done and odd.error == "the test job: ValueError: boom" and odd.result is None
