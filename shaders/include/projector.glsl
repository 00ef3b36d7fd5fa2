// The first projector (the session's video; in the deferred passes, whichever projector is
// drawn): its frustum, depth map and camera, and the video pixel of a camera-frame point through
// its lens and rolling shutter. Shared by scene.frag and decal.frag; needs lens.glsl.

uniform vec3 u_proj_position;  // projector position, ENU metres
uniform float u_proj_near;
uniform float u_proj_far;
uniform float u_proj_focal_texels; // depth-map focal length, texels
uniform sampler2D u_depth_map;
uniform float u_alpha;         // video opacity: 0 = model, 1 = video
uniform float u_bias_constant; // metres
uniform float u_bias_slope;    // depth-map texels of surface slope
uniform float u_proj_priority;  // the first projector's
uniform float u_proj_age;       // the first projector's frame's age, s

// The video camera's lens (lens.glsl): with one, u_proj_view_proj is the pinhole enclosing its
// image (the depth map's), and the video texel comes from the lens model.
uniform mat4 u_proj_view;      // projector camera-from-world (OpenGL camera frame)
uniform int u_lens_kind;       // LENS_PINHOLE, LENS_FISHEYE or LENS_BROWN
uniform vec4 u_lens_k;         // fisheye k1..k4; Brown k1, k2 (z, w unused)
uniform vec2 u_lens_p;         // Brown p1, p2
uniform float u_lens_k3;       // Brown k3
uniform vec2 u_lens_f;         // focal lengths, video pixels
uniform vec2 u_lens_c;         // principal point, video pixels
uniform vec2 u_lens_size;      // video size, pixels
uniform float u_lens_stretch;  // horizontal stretch of digital lens modes
uniform vec3 u_rs_turn;        // rolling shutter: the camera's turn from the first row to the last
                               // (radians, camera frame); the frame's pose is its middle row's
uniform vec3 u_rs_axis;        // the readout fraction of a displayed pixel: dot(axis, (u/W, v/H, 1));
                               // (0, 1, 0) for a landscape display, u for a portrait one

// The video pixel of a camera-frame point (OpenGL axes): through the lens, and with a rolling
// shutter, from the pose of the row that saw it (two fixed-point steps: the row depends on the
// pixel, the pixel on the row's pose).
vec2 video_pixel(vec3 c) {
    vec2 uv = vec2(0.0);
    vec3 p = c;
    for (int i = 0; i < 3; ++i) {
        uv = lens_distort(vec2(p.x, -p.y) / -p.z, u_lens_kind, u_lens_k, u_lens_p, u_lens_k3, u_lens_f, u_lens_c, u_lens_stretch);
        float row = clamp(dot(u_rs_axis, vec3(uv / u_lens_size, 1.0)), 0.0, 1.0) - 0.5;
        p = rotate_by(c, -row * u_rs_turn);  // the point in the camera frame of that row
    }
    return uv;
}

