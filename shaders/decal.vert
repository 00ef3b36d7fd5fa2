#version 400 core
// A deferred projector's reach on the screen (app/render/coverage.py): a convex polygon in the
// window's normalised device coordinates, drawn as a triangle fan at depth 0 (window depth
// 0.5: the projector that draws a pixel first claims it, decal.frag).
in vec2 in_ndc;

void main() {
    gl_Position = vec4(in_ndc, 0.0, 1.0);
}
