"""bench/bench_device.py's judgement of a GPU run (issue 49): what counts as a software renderer,
and which JSON shapes pass its check. The run itself is `bash bench/device.sh --dry-run`."""

from __future__ import annotations

import copy

from bench.bench_device import STEPS, check, is_software


def _complete() -> dict:
    """A result in which every step ran and holds exactly the keys it must."""
    return {
        "environment": {
            "gl": {
                "vendor": "NVIDIA Corporation",
                "renderer": "NVIDIA H100 80GB HBM3/PCIe/SSE2",
                "version": "4.6.0 NVIDIA 580.159.04",
            }
        },
        "steps": {
            s.name: {"ok": True, "figures": {k: 1.0 for k in s.keys}, "seconds": 1.0} for s in STEPS
        },
    }


def test_software_renderers_are_named_and_gpus_are_not() -> None:
    assert is_software({"vendor": "Mesa/X.org", "renderer": "llvmpipe (LLVM 15.0.6, 256 bits)"})
    assert is_software({"vendor": "Mesa", "renderer": "softpipe"})
    assert not is_software({"vendor": "NVIDIA Corporation", "renderer": "NVIDIA H100/PCIe/SSE2"})
    assert not is_software({"vendor": "AMD", "renderer": "AMD Radeon RX 7900 (radeonsi)"})


def test_a_complete_result_passes_and_each_fault_is_named() -> None:
    good = _complete()
    assert check(good, dry=True) == []

    no_renderer = copy.deepcopy(good)
    del no_renderer["environment"]["gl"]["renderer"]
    assert check(no_renderer, dry=True) == ["environment.gl.renderer missing"]

    first = STEPS[0]
    lacking = copy.deepcopy(good)
    del lacking["steps"][first.name]["figures"][first.keys[0]]
    assert check(lacking, dry=False) == [f"{first.name}: figures lack ['{first.keys[0]}']"]

    failed = copy.deepcopy(good)
    failed["steps"][first.name] = {"ok": False, "error": "Traceback ... boom"}
    (problem,) = check(failed, dry=False)
    assert problem.startswith(f"{first.name}: failed") and "boom" in problem

    missing = copy.deepcopy(good)
    del missing["steps"][first.name]
    assert check(missing, dry=False) == [f"{first.name}: not run"]


def test_only_the_windows_steps_may_be_skipped_and_only_in_a_full_run() -> None:
    window = [s for s in STEPS if s.display]
    offscreen = [s for s in STEPS if not s.display]
    assert window and offscreen
    result = _complete()
    for s in window:
        result["steps"][s.name] = {"skipped": "no X display and no Xvfb on this machine"}
    assert check(result, dry=False) == []
    assert len(check(result, dry=True)) == len(window)  # the dry run must run them all
    result["steps"][offscreen[0].name] = {"skipped": "the run's budget of 480 s was spent"}
    assert check(result, dry=False) == [
        f"{offscreen[0].name}: skipped (the run's budget of 480 s was spent)"
    ]
