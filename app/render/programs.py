"""Compile shader programs from shaders/ by name, with errors mapped to file:line."""

from __future__ import annotations

import moderngl

from app.errors import ShaderError
from app.render.shader_source import preprocess


def load_program(ctx: moderngl.Context, vertex: str, fragment: str) -> moderngl.Program:
    """Program from shaders/VERTEX and shaders/FRAGMENT (file names, e.g. 'scene.vert')."""
    vs = preprocess(vertex)
    fs = preprocess(fragment)
    try:
        return ctx.program(vertex_shader=vs.text, fragment_shader=fs.text)
    except moderngl.Error as exc:
        message = str(exc)
        located = fs.locate(message) if "fragment" in message.lower() else vs.locate(message)
        raise ShaderError(f"{vertex} + {fragment}: {located}") from exc
