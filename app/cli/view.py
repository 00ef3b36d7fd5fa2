"""`geofuse view`: the interactive viewer (app.ui.viewer)."""

from __future__ import annotations

import argparse
import logging

from app.cli.common import layers
from app.core.errors import GeofuseError
from app.ui.script import parse_script
from app.ui.viewer import Options, Viewer


def run(args: argparse.Namespace) -> int:
    if args.script is not None:
        parse_script(args.script)  # a bad script is refused before a window opens
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    inputs = list(args.manifest or [])
    for given in inputs:
        scheme, sep, _ = str(given).partition(":/")  # argparse's Path folds "//" to "/"
        if sep and scheme.isalpha() and len(scheme) > 1:
            raise GeofuseError(
                f"{scheme}://...: the window does not receive streams yet: `geofuse live URL --record FLIGHT.ts` receives and drapes one off screen, and the recording opens here (geofuse view FLIGHT.ts)"
            )
    return Viewer(
        Options(
            inputs[0] if inputs else None,
            args.size,
            args.script,
            args.screenshot,
            args.play,
            srt=args.srt,
            lens=args.lens,
            layers=layers(args),
            more=tuple(inputs[1:]),
        )
    ).run()
