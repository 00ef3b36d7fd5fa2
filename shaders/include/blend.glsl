// Where several projectors see a surface, their views are blended by a soft maximum of their
// scores (view_score): the most head-on and nearest wins, with a soft seam u_seam wide; where
// those tie, the most recent frame (the age term, one seam for a 30 fps frame interval); a
// clip's priority (10 score units a level) overrides. app/render/passes.py keeps the same
// constants. Shared by scene.frag (all views in one fragment) and decal.frag (one view a draw,
// the running blend kept per pixel between draws).
const float RANGE_SCORE_M = 2000.0;  // a view 100 m nearer counts as 0.05 of cos(incidence)
const float AGE_SCORE_PER_S = 0.6;   // a frame 1/30 s older counts as 0.02 (one seam) less
uniform float u_seam;           // score difference over which two views blend

float view_score(float priority, float cos_incidence, float range_m, float age_s) {
    return 10.0 * priority + cos_incidence - range_m / RANGE_SCORE_M - age_s * AGE_SCORE_PER_S;
}

// Running soft maximum: the views' colours and opacities weighted by exp((score - best) / u_seam).
// A new best rescales what was summed by exp((best - score) / u_seam) and weighs 1; otherwise
// the new view weighs exp((score - best) / u_seam): one exponential either way, no branch.
void add_view(inout vec4 sum, inout float weight, inout float best, float score, vec3 colour, float alpha) {
    float e = exp(-abs(score - best) / u_seam);
    bool higher = score > best;
    float k = higher ? e : 1.0;
    float w = higher ? 1.0 : e;
    sum = sum * k + w * vec4(colour, alpha);
    weight = weight * k + w;
    best = max(best, score);
}

