#version 400 core
// Position pass: each pixel's world position (ENU metres, origin-relative) and a hit flag in w,
// for measuring where a camera's pixels land on the model (accuracy benchmark).
in vec3 v_world;
in vec2 v_uv;
in vec4 v_color;
out vec4 f_position;

void main() {
    f_position = vec4(v_world, 1.0);
}
