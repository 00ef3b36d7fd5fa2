"""Compile shader programs from shaders/ by name, with errors mapped to file:line."""

from __future__ import annotations

import moderngl
import numpy as np

from app.core.errors import ShaderError
from app.render.shader_source import preprocess


def load_program(
    ctx: moderngl.Context, vertex: str, fragment: str, defines: dict[str, int] | None = None
) -> moderngl.Program:
    """Program from shaders/VERTEX and shaders/FRAGMENT (file names, e.g. 'scene.vert'), both
    compiled with `defines` (a specialised variant, see shader_source.preprocess)."""
    vs = preprocess(vertex, defines=defines)
    fs = preprocess(fragment, defines=defines)
    try:
        return ctx.program(vertex_shader=vs.text, fragment_shader=fs.text)
    except moderngl.Error as exc:
        message = str(exc)
        located = fs.locate(message) if "fragment" in message.lower() else vs.locate(message)
        raise ShaderError(f"{vertex} + {fragment}: {located}") from exc


class Uniforms:
    """Sets a program's uniforms by name, leaving out those its variant lacks (a specialised
    variant's compiler drops what it does not use) and fitting arrays to the length the program
    keeps. That length is the driver's: Mesa keeps up to the highest element a variant reads
    (EXTRA_COUNT of a MAX_EXTRA array), NVIDIA keeps the whole declared array wherever it is
    indexed in a loop; elements beyond those given repeat the last one (never read)."""

    def __init__(self, program: moderngl.Program) -> None:
        self.program = program

    def __setitem__(self, name: str, value: object) -> None:
        member = self.program.get(name, None)
        if member is None:
            return
        if isinstance(value, list):  # an array's elements
            value = _fitted(value, member.array_length)
            value = value[0] if member.array_length == 1 else value
        member.value = value

    def matrices(self, name: str, matrices: list[np.ndarray]) -> None:
        """4x4 row-major matrices (one, or an array's elements) as the column-major floats GLSL
        reads."""
        member = self.program.get(name, None)
        if member is None:
            return
        kept = _fitted(list(matrices), member.array_length)
        stack = np.stack([np.asarray(m, np.float32).T for m in kept])
        member.write(stack.tobytes())


def _fitted(values: list, length: int) -> list:
    """`values` cut or padded (the last one repeated) to `length` elements."""
    if not values:
        raise ValueError("an array uniform needs at least one element")
    return values[:length] + [values[-1]] * max(0, length - len(values))
