// Projective texture mapping from a "depth camera" (the video's camera), shared by the scene
// shader of the viewer, the off-screen renderer and the tests.
//
// Conventions: the depth map holds window depth in [0, 1] of a perspective projection with
// planes u_proj_near / u_proj_far (metres); the video texture's row 0 is the image's top row.

// World position -> depth-camera clip coordinates. Returns false when the point lies behind the
// camera or outside the frustum in x, y or z (the paper's "scissor test").
bool projector_ndc(vec3 world, mat4 proj_view_proj, out vec3 ndc, out float eye_depth) {
    vec4 clip = proj_view_proj * vec4(world, 1.0);
    eye_depth = clip.w;  // distance along the optical axis, metres
    if (clip.w <= 0.0) {
        ndc = vec3(2.0);
        return false;
    }
    ndc = clip.xyz / clip.w;
    return all(lessThanEqual(abs(ndc), vec3(1.0)));
}

// Window depth in [0, 1] -> distance along the optical axis in metres.
float linearise_depth(float window_depth, float near, float far) {
    float z = window_depth * 2.0 - 1.0;
    return 2.0 * near * far / (far + near - z * (far - near));
}

// Depth bias in metres: a constant plus a slope-scaled part. `texel_m` is the size of one
// depth-map texel at the fragment's distance; `cos_incidence` the cosine between the surface
// normal and the direction to the depth camera.
float projector_bias(float constant_m, float slope_texels, float texel_m, float cos_incidence) {
    float c = clamp(cos_incidence, 0.05, 1.0);
    float tan_incidence = sqrt(1.0 - c * c) / c;
    return constant_m + slope_texels * texel_m * tan_incidence;
}

// The depth test. With `neighbourhood` on, the paper's nine-case rule: the fragment must be
// visible at its own texel and at each of the eight neighbours that lie inside the map (edge
// and corner texels have fewer); otherwise only its own texel is tested.
bool projector_visible(sampler2D depth_map, ivec2 texel, float eye_depth, float bias_m,
                       float near, float far, bool neighbourhood) {
    ivec2 size = textureSize(depth_map, 0);
    int reach = neighbourhood ? 1 : 0;
    for (int dy = -reach; dy <= reach; ++dy) {
        for (int dx = -reach; dx <= reach; ++dx) {
            ivec2 t = texel + ivec2(dx, dy);
            if (any(lessThan(t, ivec2(0))) || any(greaterThanEqual(t, size))) {
                continue;  // neighbour outside the image: not part of this case
            }
            float occluder = linearise_depth(texelFetch(depth_map, t, 0).r, near, far);
            if (eye_depth - bias_m > occluder) {
                return false;
            }
        }
    }
    return true;
}
