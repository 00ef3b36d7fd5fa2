// The video frame's colour at a point of the displayed image.
//
// Stills arrive as RGB already turned for display (u_video_rotation = 0). Playback frames arrive
// as stored Y, U, V planes (row 0 = the top of the stored image) and are turned here: the display
// is the stored image turned clockwise by u_video_rotation degrees. Which of the two a shader
// reads is fixed when it is compiled (VIDEO_YUV: 0 RGB, 1 three planes, 2 Y and a two-channel
// U, V texture in u_video_u, as a further clip's playback frame arrives).

#ifndef VIDEO_YUV
#define VIDEO_YUV 0
#endif
uniform int u_video_rotation;   // 0, 90, 180, 270 (clockwise, a phone's rotate tag)
uniform sampler2D u_video;      // RGB still, or the Y plane
uniform sampler2D u_video_u;    // U (VIDEO_YUV 1), or U and V (VIDEO_YUV 2)
uniform sampler2D u_video_v;
uniform mat3 u_yuv_matrix;      // (Y, Cb, Cr) minus offsets -> RGB, BT.601 or BT.709
uniform vec3 u_yuv_offset;      // limited range: (16, 128, 128) / 255

// display: (u, v) in [0, 1] with v down from the displayed image's top -> the coordinates in the
// stored image, which the display shows turned clockwise by `rotation` degrees.
vec2 turned_coords(vec2 display, int rotation) {
    if (rotation == 90) {
        return vec2(display.y, 1.0 - display.x);
    } else if (rotation == 180) {
        return vec2(1.0 - display.x, 1.0 - display.y);
    } else if (rotation == 270) {
        return vec2(1.0 - display.y, display.x);
    }
    return display;
}

vec2 stored_coords(vec2 display) {
    return turned_coords(display, u_video_rotation);
}

// (Y, Cb, Cr) in [0, 1] -> RGB by the stream's matrix and range.
vec3 yuv_colour(vec3 yuv, mat3 matrix, vec3 offset) {
    return clamp(matrix * (yuv - offset), 0.0, 1.0);
}

vec3 video_colour(vec2 display) {
    vec2 st = stored_coords(display);
#if VIDEO_YUV == 2
    vec3 yuv = vec3(texture(u_video, st).r, texture(u_video_u, st).rg);
    return yuv_colour(yuv, u_yuv_matrix, u_yuv_offset);
#elif VIDEO_YUV
    vec3 yuv = vec3(texture(u_video, st).r, texture(u_video_u, st).r, texture(u_video_v, st).r);
    return yuv_colour(yuv, u_yuv_matrix, u_yuv_offset);
#else
    return texture(u_video, st).rgb;
#endif
}
