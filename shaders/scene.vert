#version 400 core
// Scene pass: world (ENU, origin-relative metres) positions to the window camera, and to each
// projector's clip coordinates (affine in the position, so interpolated exactly: cheaper here,
// once a vertex, than a matrix product in every fragment).
#include "variant.glsl"
uniform mat4 u_view_proj;
#if PROJECTION
uniform mat4 u_proj_view_proj;  // the first projector's clip-from-world
out vec4 v_proj_clip;
#endif
#if EXTRA_COUNT > 0
uniform mat4 u_extra_view_proj[EXTRA_COUNT];  // the further projectors'
out vec4 v_extra_clip[EXTRA_COUNT];
#endif

in vec3 in_position;
in vec2 in_uv;
in vec4 in_color;

out vec3 v_world;
out vec2 v_uv;
out vec4 v_color;

void main() {
    v_world = in_position;
#if PROJECTION
    v_proj_clip = u_proj_view_proj * vec4(in_position, 1.0);
#endif
#if EXTRA_COUNT > 0
    for (int i = 0; i < EXTRA_COUNT; ++i) {
        v_extra_clip[i] = u_extra_view_proj[i] * vec4(in_position, 1.0);
    }
#endif
    v_uv = in_uv;
    v_color = in_color;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
