#version 400 core
// Scene pass with projective video texturing (paper 2.2.2).
//
// Compiled in variants: include/variant.glsl.
#include "variant.glsl"
#include "projective.glsl"
#include "lens.glsl"
#include "video.glsl"
#include "surface.glsl"

uniform sampler2D u_base_texture;
uniform bool u_has_texture;
uniform vec3 u_eye;            // window camera position, ENU metres
uniform vec3 u_light_dir;      // unit vector toward the light, ENU

#include "projector.glsl"
#include "blend.glsl"

// Further projectors: the other clips shown at once, each with its own pose, lens (no rolling
// shutter), depth map and video (an RGB still or a playback frame's planes). Where several see a
// fragment, the views are blended by a soft maximum of their scores (view_score): the most
// head-on and nearest wins, with a soft seam u_seam wide; where those tie, the most recent frame
// (the age term, one seam for a 30 fps frame interval); a clip's priority (10 score units a
// level) overrides (include/blend.glsl).
uniform mat4 u_extra_view[MAX_EXTRA];
uniform vec3 u_extra_position[MAX_EXTRA];
uniform float u_extra_near[MAX_EXTRA];
uniform float u_extra_far[MAX_EXTRA];
uniform float u_extra_focal_texels[MAX_EXTRA];
uniform float u_extra_priority[MAX_EXTRA];
uniform float u_extra_age[MAX_EXTRA];    // how long before the drawn moment its frame was taken, s
uniform float u_extra_alpha[MAX_EXTRA];  // each further clip's opacity (the first's: u_alpha)
uniform int u_extra_lens_kind[MAX_EXTRA];  // LENS_FISHEYE or LENS_BROWN where EXTRA_LENSES says
uniform vec4 u_extra_lens_k[MAX_EXTRA];
uniform vec2 u_extra_lens_p[MAX_EXTRA];
uniform float u_extra_lens_k3[MAX_EXTRA];
uniform vec2 u_extra_lens_f[MAX_EXTRA];
uniform vec2 u_extra_lens_c[MAX_EXTRA];
uniform vec2 u_extra_lens_size[MAX_EXTRA];
uniform float u_extra_lens_stretch[MAX_EXTRA];
uniform sampler2D u_extra_depth[MAX_EXTRA];
uniform sampler2D u_extra_video[MAX_EXTRA];   // an RGB still (display-oriented), or the Y plane
// Playback frames (EXTRA_YUV), as video.glsl reads the first projector's:
uniform sampler2D u_extra_chroma[MAX_EXTRA];  // U and V in one two-channel texture
uniform int u_extra_rotation[MAX_EXTRA];      // the display: stored turned clockwise, degrees
uniform mat3 u_extra_yuv_matrix[MAX_EXTRA];
uniform vec3 u_extra_yuv_offset[MAX_EXTRA];

// Error overlay (sessions with ground truth): the true camera's position map. The video texel
// that lands on this fragment truly shows the model point stored at the same texel.
uniform sampler2D u_truth_positions;
uniform float u_error_scale_m;  // the colour ramp's top, metres

in vec3 v_world;
#if PROJECTION
in vec4 v_proj_clip;       // the first projector's clip coordinates (scene.vert)
#endif
#if EXTRA_COUNT > 0
in vec4 v_extra_clip[EXTRA_COUNT];  // the further projectors'
#endif
in vec2 v_uv;
in vec4 v_color;

layout(location = 0) out vec4 f_color;
#if GBUFFER
// The deferred projectors' surface (app/render/decals.py): the distance from the eye (m, float
// bits; 0 where nothing was drawn) and the normal facing the eye (octahedral, 16 bits a side).
layout(location = 1) out uvec2 f_surface;
#endif

// Green (0 m) -> yellow (half the scale) -> red (the scale and beyond).
vec3 error_colour(float metres) {
    float x = clamp(metres / u_error_scale_m, 0.0, 1.0);
    vec3 green = vec3(0.10, 0.80, 0.25);
    vec3 yellow = vec3(1.00, 0.85, 0.10);
    vec3 red = vec3(0.90, 0.10, 0.10);
    return x < 0.5 ? mix(green, yellow, 2.0 * x) : mix(yellow, red, 2.0 * x - 1.0);
}

vec3 model_colour(vec3 normal) {
    vec4 base = v_color;
    if (u_has_texture) {
        base *= texture(u_base_texture, v_uv);
    }
    float light = 0.6 + 0.4 * max(dot(normal, u_light_dir), 0.0);
    return base.rgb * light;
}

#if EXTRA_COUNT > 0
// Further projector i's video at a point of its displayed image.
vec3 extra_colour(int i, sampler2D video, sampler2D chroma, bool yuv, vec2 display) {
    if (yuv) {
        vec2 st = turned_coords(display, u_extra_rotation[i]);
        vec3 c = vec3(texture(video, st).r, texture(chroma, st).rg);
        return yuv_colour(c, u_extra_yuv_matrix[i], u_extra_yuv_offset[i]);
    }
    return texture(video, display).rgb;
}

// Further projector i (its depth map and video passed as samplers; its lens and whether its
// video is planes known when the variant is compiled) added to the running blend where it sees
// the fragment.
void add_extra(int i, sampler2D depth_map, sampler2D video, sampler2D chroma, bool has_lens, bool yuv,
               vec3 normal, inout vec4 sum, inout float weight, inout float best) {
    vec3 ndc;
    float eye_depth;
    if (!projector_ndc(v_extra_clip[i], ndc, eye_depth)) {
        return;
    }
    vec2 st = ndc.xy * 0.5 + 0.5;
    ivec2 size = textureSize(depth_map, 0);
    ivec2 texel = clamp(ivec2(st * vec2(size)), ivec2(0), size - 1);
    vec3 to_projector = u_extra_position[i] - v_world;
    float range_m = length(to_projector);
    to_projector /= range_m;
    float cos_incidence = abs(dot(normal, to_projector));
    float bias = projector_bias(u_bias_constant, u_bias_slope, eye_depth / u_extra_focal_texels[i], cos_incidence);
    vec2 video_st = vec2(st.x, 1.0 - st.y);
    if (has_lens) {
        vec3 c = (u_extra_view[i] * vec4(v_world, 1.0)).xyz;
        vec2 uv = lens_distort(vec2(c.x, -c.y) / -c.z, u_extra_lens_kind[i], u_extra_lens_k[i], u_extra_lens_p[i],
                               u_extra_lens_k3[i], u_extra_lens_f[i], u_extra_lens_c[i], u_extra_lens_stretch[i]);
        video_st = uv / u_extra_lens_size[i];
        if (any(lessThan(video_st, vec2(0.0))) || any(greaterThan(video_st, vec2(1.0)))) {
            return;
        }
    }
    if (projector_visible(depth_map, texel, eye_depth, bias, u_extra_near[i], u_extra_far[i], NEIGHBOURHOOD != 0)) {
        float score = view_score(u_extra_priority[i], cos_incidence, range_m, u_extra_age[i]);
        add_view(sum, weight, best, score, extra_colour(i, video, chroma, yuv, video_st), u_extra_alpha[i]);
    }
}

#define ADD_EXTRA(i) add_extra(i, u_extra_depth[i], u_extra_video[i], u_extra_chroma[i], ((EXTRA_LENSES >> i) & 1) != 0, ((EXTRA_YUV >> i) & 1) != 0, normal, sum, weight, best)
#endif

void main() {
    vec3 normal = normalize(cross(dFdx(v_world), dFdy(v_world)));
    if (dot(normal, u_eye - v_world) < 0.0) {
        normal = -normal;
    }
    vec3 colour = model_colour(normal);
    vec4 sum = vec4(0.0);  // colour and opacity of the views, weighted
    float weight = 0.0;
    float best = -1e30;

#if PROJECTION
    vec3 ndc;
    float eye_depth;
    vec2 truth_st = vec2(-1.0);
    if (projector_ndc(v_proj_clip, ndc, eye_depth)) {
        vec2 st = ndc.xy * 0.5 + 0.5;  // bottom-left origin
        ivec2 size = textureSize(u_depth_map, 0);
        ivec2 texel = clamp(ivec2(st * vec2(size)), ivec2(0), size - 1);
        vec3 to_projector = u_proj_position - v_world;
        float range_m = length(to_projector);
        to_projector /= range_m;
        float texel_m = eye_depth / u_proj_focal_texels;
        float cos_incidence = abs(dot(normal, to_projector));
        float bias = projector_bias(u_bias_constant, u_bias_slope, texel_m, cos_incidence);
        vec2 video_st = vec2(st.x, 1.0 - st.y);  // top-left origin
        bool in_image = true;
#if EXACT_VIDEO
        vec2 uv = video_pixel((u_proj_view * vec4(v_world, 1.0)).xyz);
        video_st = uv / u_lens_size;
        in_image = all(greaterThanEqual(video_st, vec2(0.0))) && all(lessThanEqual(video_st, vec2(1.0)));
#endif
        if (in_image && projector_visible(u_depth_map, texel, eye_depth, bias, u_proj_near, u_proj_far, NEIGHBOURHOOD != 0)) {
            float score = view_score(u_proj_priority, cos_incidence, range_m, u_proj_age);
#if EXTRA_COUNT == 0
            sum = vec4(video_colour(video_st), u_alpha);  // add_view of a single view
            weight = 1.0;
#else
            add_view(sum, weight, best, score, video_colour(video_st), u_alpha);
#endif
            truth_st = st;
        }
    }
#endif
#if EXTRA_COUNT > 0
    ADD_EXTRA(0);
#endif
#if EXTRA_COUNT > 1
    ADD_EXTRA(1);
#endif
#if EXTRA_COUNT > 2
    ADD_EXTRA(2);
#endif
#if EXTRA_COUNT > 3
    ADD_EXTRA(3);
#endif
#if EXTRA_COUNT > 4
    ADD_EXTRA(4);
#endif
#if EXTRA_COUNT > 5
    ADD_EXTRA(5);
#endif
#if EXTRA_COUNT > 6
    ADD_EXTRA(6);
#endif
    if (weight > 0.0) {
        colour = mix(colour, sum.rgb / weight, sum.a / weight);
#if PROJECTION && ERROR_OVERLAY
        if (truth_st.x >= 0.0) {
            vec4 truth = texture(u_truth_positions, truth_st);
            if (truth.w > 0.5) {
                colour = mix(colour, error_colour(distance(v_world, truth.xyz)), 0.7);
            }
        }
#endif
    }
    f_color = vec4(colour, 1.0);
#if GBUFFER
    f_surface = uvec2(floatBitsToUint(distance(v_world, u_eye)), pack_normal(normal));
#endif
}
