// The scene pass's variant switches (app/render/passes.py, ScenePass), shared by scene.vert and
// scene.frag. What a frame switches on or off is a preprocessor symbol, not a uniform, so that a
// variant holds only the code it runs: a software rasteriser (Mesa's llvmpipe) runs both sides of
// every branch on its SIMD lanes, so a path switched off by a uniform costs as much as one
// switched on (docs/PERFORMANCE.md, "Shader variants"). The defaults below stand where the
// program is compiled without them.
#ifndef PROJECTION
#define PROJECTION 1      // the first projector (the session's video) is drawn
#endif
#ifndef EXACT_VIDEO
#define EXACT_VIDEO 0     // its video looked up through its lens and rolling-shutter model
#endif
#ifndef NEIGHBOURHOOD
#define NEIGHBOURHOOD 1   // the paper's nine-case depth test (else the texel's own depth)
#endif
#ifndef ERROR_OVERLAY
#define ERROR_OVERLAY 0   // the error colours of sessions with ground truth
#endif
#ifndef EXTRA_COUNT
#define EXTRA_COUNT 0     // further projectors (other clips), 0 to MAX_EXTRA
#endif
#ifndef EXTRA_LENSES
#define EXTRA_LENSES 0    // bit i set: further projector i has a lens model
#endif
#ifndef EXTRA_YUV
#define EXTRA_YUV 0       // bit i set: further projector i's video is a playback frame's planes
#endif
#ifndef GBUFFER
#define GBUFFER 0         // also write the surface for the deferred projectors (decal.frag)
#endif
const int MAX_EXTRA = 7;  // app/render/passes.py MAX_EXTRA
