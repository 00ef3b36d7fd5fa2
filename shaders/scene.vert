#version 400 core
// Scene pass: world (ENU, origin-relative metres) positions to the window camera.
uniform mat4 u_view_proj;

in vec3 in_position;
in vec2 in_uv;
in vec4 in_color;

out vec3 v_world;
out vec2 v_uv;
out vec4 v_color;

void main() {
    v_world = in_position;
    v_uv = in_uv;
    v_color = in_color;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
