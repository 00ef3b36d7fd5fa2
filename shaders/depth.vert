#version 400 core
// Depth pass: the scene seen from the projector; only depth is written.
uniform mat4 u_view_proj;
in vec3 in_position;

void main() {
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
