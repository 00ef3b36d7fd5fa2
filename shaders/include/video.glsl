// The video frame's colour at a point of the displayed image.
//
// Stills arrive as RGB already turned for display (u_video_rotation = 0). Playback frames arrive
// as stored Y, U, V planes (row 0 = the top of the stored image) and are turned here: the display
// is the stored image turned clockwise by u_video_rotation degrees. Which of the two a shader
// reads is fixed when it is compiled (VIDEO_YUV, 1 for planes).

#ifndef VIDEO_YUV
#define VIDEO_YUV 0
#endif
uniform int u_video_rotation;   // 0, 90, 180, 270 (clockwise, a phone's rotate tag)
uniform sampler2D u_video;      // RGB still, or the Y plane
uniform sampler2D u_video_u;
uniform sampler2D u_video_v;
uniform mat3 u_yuv_matrix;      // (Y, Cb, Cr) minus offsets -> RGB, BT.601 or BT.709
uniform vec3 u_yuv_offset;      // limited range: (16, 128, 128) / 255

// display: (u, v) in [0, 1] with v down from the displayed image's top -> stored image coords.
vec2 stored_coords(vec2 display) {
    if (u_video_rotation == 90) {
        return vec2(display.y, 1.0 - display.x);
    } else if (u_video_rotation == 180) {
        return vec2(1.0 - display.x, 1.0 - display.y);
    } else if (u_video_rotation == 270) {
        return vec2(1.0 - display.y, display.x);
    }
    return display;
}

vec3 video_colour(vec2 display) {
    vec2 st = stored_coords(display);
#if VIDEO_YUV
    vec3 yuv = vec3(texture(u_video, st).r, texture(u_video_u, st).r, texture(u_video_v, st).r);
    return clamp(u_yuv_matrix * (yuv - u_yuv_offset), 0.0, 1.0);
#else
    return texture(u_video, st).rgb;
#endif
}
