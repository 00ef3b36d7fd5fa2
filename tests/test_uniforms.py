"""Array uniforms set through app.render.programs.Uniforms on a driver that keeps the whole
declared array. NVIDIA's compiler keeps all MAX_EXTRA elements of the further projectors' arrays
where Mesa keeps only the EXTRA_COUNT a variant reads; setting fewer elements than the driver
kept raised "invalid uniform size" and stopped every frame with several clips on the first GPU
the renderer met (issue 49). Mesa keeps the whole array too when the loop's bound is a uniform,
which is how this test puts llvmpipe in NVIDIA's place."""

from __future__ import annotations

import numpy as np
import pytest

from app.render.programs import Uniforms

pytestmark = pytest.mark.gl

VERTEX = """#version 400 core
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
"""

FRAGMENT = """#version 400 core
uniform vec3 u_a[7];
uniform mat4 u_m[7];
uniform int u_n;
out vec4 f_colour;
void main() {
    vec3 s = vec3(0.0);
    for (int i = 0; i < u_n; ++i) s += u_a[i] + u_m[i][3].xyz;
    f_colour = vec4(s, 1.0);
}
"""


def test_fewer_elements_than_the_driver_keeps_are_padded_and_drawn(gl_ctx) -> None:
    ctx = gl_ctx
    program = ctx.program(vertex_shader=VERTEX, fragment_shader=FRAGMENT)
    # The precondition: this driver kept the whole array (else the test would prove nothing).
    assert program["u_a"].array_length == 7 and program["u_m"].array_length == 7
    u = Uniforms(program)
    u["u_a"] = [(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)]
    shift = np.eye(4)
    shift[:3, 3] = (10.0, 20.0, 30.0)  # row-major: a translation, read back as column 3
    u.matrices("u_m", [np.eye(4), shift])
    u["u_n"] = 2
    values = program["u_a"].value
    assert values[:2] == [(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)]
    assert all(v == (4.0, 5.0, 6.0) for v in values[2:])  # the last one repeated, never read

    target = ctx.texture((1, 1), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[target])
    tri = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], np.float32).tobytes())
    vao = ctx.vertex_array(program, [(tri, "2f", "in_pos")])
    fbo.use()
    fbo.clear()
    vao.render()
    got = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32)
    # u_a[0] + u_a[1] + column 3 of u_m[0] (0, 0, 0) and of u_m[1] (10, 20, 30)
    np.testing.assert_allclose(got[:3], [15.0, 27.0, 39.0])
    for obj in (vao, tri, fbo, target, program):
        obj.release()


def test_more_elements_than_the_driver_keeps_are_cut(gl_ctx) -> None:
    program = gl_ctx.program(
        vertex_shader=VERTEX,
        fragment_shader=FRAGMENT.replace("i < u_n", "i < 2"),  # a constant bound: Mesa trims
    )
    kept = program["u_a"].array_length
    assert kept < 7
    Uniforms(program)["u_a"] = [(float(i), 0.0, 0.0) for i in range(7)]
    assert [v[0] for v in program["u_a"].value] == [float(i) for i in range(kept)]
    program.release()
