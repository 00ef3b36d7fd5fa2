// The surface a window pixel sees, as the scene pass writes it for the deferred projectors
// (scene.frag with GBUFFER) and decal.frag reads it: the normal, facing the eye, in 32 bits
// (octahedral encoding, 16 bits a side: within 1e-4 rad).

vec2 sign_not_zero(vec2 v) {
    return vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

uint pack_normal(vec3 n) {
    n /= abs(n.x) + abs(n.y) + abs(n.z);
    vec2 e = n.z >= 0.0 ? n.xy : (1.0 - abs(n.yx)) * sign_not_zero(n.xy);
    uvec2 q = uvec2(clamp(round(e * 32767.0) + 32767.0, 0.0, 65534.0));
    return q.x | (q.y << 16u);
}

vec3 unpack_normal(uint bits) {
    vec2 e = (vec2(float(bits & 0xFFFFu), float(bits >> 16u)) - 32767.0) / 32767.0;
    vec3 n = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (n.z < 0.0) {
        n.xy = (1.0 - abs(n.yx)) * sign_not_zero(n.xy);
    }
    return normalize(n);
}
