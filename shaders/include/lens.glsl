// Real lenses in the projection, per fragment, forward (camera ray -> distorted pixel). Mirrors
// app/lens.py `Lens.distort`: Kannala-Brandt fisheye (OpenCV fisheye, k1..k4) or Brown-Conrady
// (k1, k2, p1, p2, k3), then the horizontal stretch of digital lens modes about the centre.
//
// a, b: normalised coordinates in OpenCV's camera frame (x right, y down, z forward).
// Returns the pixel (u right, v down) of the video image.

const int LENS_PINHOLE = 0;
const int LENS_FISHEYE = 1;
const int LENS_BROWN = 2;

// v rotated by the rotation vector r (axis * angle, radians): Rodrigues' formula.
vec3 rotate_by(vec3 v, vec3 r) {
    float angle = length(r);
    if (angle < 1e-12) {
        return v;
    }
    vec3 k = r / angle;
    return v * cos(angle) + cross(k, v) * sin(angle) + k * dot(k, v) * (1.0 - cos(angle));
}

vec2 lens_distort(vec2 ab, int kind, vec4 k, vec2 p, float k3, vec2 f, vec2 c, float stretch) {
    vec2 xy = ab;
    if (kind == LENS_FISHEYE) {
        float r = length(ab);
        float theta = atan(r);
        float t2 = theta * theta;
        float theta_d = theta * (1.0 + t2 * (k.x + t2 * (k.y + t2 * (k.z + t2 * k.w))));
        xy = r > 1e-9 ? ab * (theta_d / r) : ab;
    } else if (kind == LENS_BROWN) {
        float r2 = dot(ab, ab);
        float radial = 1.0 + r2 * (k.x + r2 * (k.y + r2 * k3));
        xy = ab * radial + vec2(2.0 * p.x * ab.x * ab.y + p.y * (r2 + 2.0 * ab.x * ab.x),
                                p.x * (r2 + 2.0 * ab.y * ab.y) + 2.0 * p.y * ab.x * ab.y);
    }
    vec2 uv = f * xy + c;
    uv.x = c.x + stretch * (uv.x - c.x);
    return uv;
}
