// Projective texture mapping from the projector (the video's camera; the paper's "depth camera"), shared by the scene
// shader of the viewer, the off-screen renderer and the tests.
//
// Conventions: the depth map holds window depth in [0, 1] of a perspective projection with
// planes u_proj_near / u_proj_far (metres); the video texture's row 0 is the image's top row.

// A point's clip coordinates in the projector's frustum -> its normalised device coordinates
// and distance along the optical axis. Returns false when the point lies behind the camera or
// outside the frustum in x, y or z (the paper's "scissor test").
bool projector_ndc(vec4 clip, out vec3 ndc, out float eye_depth) {
    eye_depth = clip.w;  // distance along the optical axis, metres
    if (clip.w <= 0.0) {
        ndc = vec3(2.0);
        return false;
    }
    ndc = clip.xyz / clip.w;
    return all(lessThanEqual(abs(ndc), vec3(1.0)));
}

// Distance along the optical axis (metres, > 0) -> window depth in [0, 1] of the projection
// with planes near/far. Monotonic, so comparisons can be made in either space.
float window_depth(float eye_depth, float near, float far) {
    float ndc = (far + near) / (far - near) - 2.0 * far * near / ((far - near) * eye_depth);
    return ndc * 0.5 + 0.5;
}

// Depth bias in metres: a constant plus a slope-scaled part. `texel_m` is the size of one
// depth-map texel at the fragment's distance; `cos_incidence` the cosine between the surface
// normal and the direction to the projector. The incidence is followed down to 0.6 deg
// (cos 0.01): a hand-held camera's own ground, metres below it, is seen at 1-3 deg out to tens
// of metres, where a clamp at 3 deg left bands of model colour (tests/test_render_projection.py).
float projector_bias(float constant_m, float slope_texels, float texel_m, float cos_incidence) {
    float c = clamp(cos_incidence, 0.01, 1.0);
    float tan_incidence = sqrt(1.0 - c * c) / c;
    return constant_m + slope_texels * texel_m * tan_incidence;
}

// The nearest depth among a texel and each of its eight neighbours that lie inside the map (the
// paper's nine-case rule: edge and corner texels have fewer neighbours). Four gathers at the
// texel's corners fetch the 3x3 block; the map is sampled clamp-to-edge, so a neighbour outside
// the image reads as an in-image texel that is already part of the block and adds nothing.
float neighbourhood_min_depth(sampler2D depth_map, ivec2 texel) {
    vec2 size = vec2(textureSize(depth_map, 0));
    vec2 corner = vec2(texel) / size;  // between texels texel-1 and texel
    vec2 step = 1.0 / size;
    vec4 m = min(min(textureGather(depth_map, corner), textureGather(depth_map, corner + vec2(step.x, 0.0))),
                 min(textureGather(depth_map, corner + vec2(0.0, step.y)), textureGather(depth_map, corner + step)));
    return min(min(m.x, m.y), min(m.z, m.w));
}

// The depth test: the fragment, pulled toward the projector by the bias, must not lie behind
// the depth map at its texel (or, with `neighbourhood`, at any of the nine-case texels).
bool projector_visible(sampler2D depth_map, ivec2 texel, float eye_depth, float bias_m,
                       float near, float far, bool neighbourhood) {
    float mine = window_depth(max(eye_depth - bias_m, near), near, far);
    float occluder = neighbourhood ? neighbourhood_min_depth(depth_map, texel) : texelFetch(depth_map, texel, 0).r;
    return mine <= occluder;
}
