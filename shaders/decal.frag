#version 400 core
// One projector drawn as a deferred decal (app/render/decals.py): the scene was drawn once
// (scene.frag with GBUFFER: its colour, and the surface each pixel sees), and each projector
// shades only the pixels of its reach (decal.vert), with the same depth test and video lookup as
// scene.frag's forward projection. Projectors are drawn best first (priority, then the youngest
// frame); the first that sees a pixel claims it (a depth write the later projectors' early depth
// test rejects), so overlaps cost once; the video is blended over the model by the fixed
// function (source alpha = the clip's opacity).
//
// Variants: EXACT_VIDEO (lens or rolling shutter), VIDEO_YUV (0 RGB, 1 three planes, 2 Y + UV),
// NEIGHBOURHOOD (the nine-case depth test).
#ifndef EXACT_VIDEO
#define EXACT_VIDEO 0
#endif
#ifndef NEIGHBOURHOOD
#define NEIGHBOURHOOD 1
#endif
#include "projective.glsl"
#include "lens.glsl"
#include "video.glsl"
#include "surface.glsl"
#include "projector.glsl"

uniform mat4 u_proj_view_proj;   // the projector's clip-from-world
uniform vec3 u_eye;              // the window camera's position, ENU metres
uniform mat4 u_view_inverse;     // world-from-camera of the window camera (OpenGL camera frame)
uniform vec4 u_pixel_ray;        // camera-frame ray of a pixel: ((x - a) / b, (y - c) / d, -1)
uniform usampler2D u_surface;    // (distance from the eye as float bits, packed normal); 0: sky

out vec4 f_color;                // the video and its opacity, blended over the model

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    uvec2 surface = texelFetch(u_surface, px, 0).rg;
    float range_eye = uintBitsToFloat(surface.r);
    if (range_eye <= 0.0) {
        discard;  // nothing drawn here (sky)
    }
    vec3 ray = normalize(mat3(u_view_inverse) * vec3((gl_FragCoord.xy - u_pixel_ray.xz) / u_pixel_ray.yw, -1.0));
    vec3 world = u_eye + ray * range_eye;
    vec3 normal = unpack_normal(surface.g);

    vec4 clip = u_proj_view_proj * vec4(world, 1.0);
    vec3 ndc;
    float eye_depth;
    if (!projector_ndc(clip, ndc, eye_depth)) {
        discard;
    }
    vec2 st = ndc.xy * 0.5 + 0.5;
    ivec2 size = textureSize(u_depth_map, 0);
    ivec2 texel = clamp(ivec2(st * vec2(size)), ivec2(0), size - 1);
    float cos_incidence = abs(dot(normal, normalize(u_proj_position - world)));
    float bias = projector_bias(u_bias_constant, u_bias_slope, eye_depth / u_proj_focal_texels, cos_incidence);
    vec2 video_st = vec2(st.x, 1.0 - st.y);
#if EXACT_VIDEO
    video_st = video_pixel((u_proj_view * vec4(world, 1.0)).xyz) / u_lens_size;
    if (any(lessThan(video_st, vec2(0.0))) || any(greaterThan(video_st, vec2(1.0)))) {
        discard;
    }
#endif
    if (!projector_visible(u_depth_map, texel, eye_depth, bias, u_proj_near, u_proj_far, NEIGHBOURHOOD != 0)) {
        discard;
    }
    f_color = vec4(video_colour(video_st), u_alpha);
}
