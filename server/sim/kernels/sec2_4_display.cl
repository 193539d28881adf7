// Sec. 2.4 and Eq. 12: assemble the displayed value per screen pixel. Tone curve on the
// Purkinje-shifted luminance (Eq. 1, 13), mesopic hue shift, afterimage gain and bleaching
// term read at the retinal position x - gaze with the foveal fall-off, gamut, gamma.
// One work-item makes VEC neighbouring pixels of a row; global size (ceil(W / VEC), H).

// Largest t in [0,1] keeping a + t (rgb - a) inside the cube, for a grey a: never flip hue.
HOT floatv gamut_t(floatv a, floatv e, floatv t) {
    floatv lim = (e > 0.0f ? 1.0f - a : -a) / e;  // inf or NaN where e = 0: not taken
    return (e != 0.0f && lim < t) ? lim : t;
}

// The first half of composev: tone curve with Purkinje and hue shift, linear RGB before Eq. 12.
// What a late gaze warp sends (compose_base): none of it depends on the gaze. eyes: 1 open, 0
// closed (no light: returned at once, in place of three multiplies a run, compose 0.98x).
HOT rgbv_t basev(__constant const params_t *P, __global const ushort *G,
                    __global const float *rho_full, __global const float *A, int W, int H,
                    float eyes, int x, int y) {
    rgbv_t J = {0.0f, 0.0f, 0.0f};
    if (eyes == 0.0f) return J;  // closed: no light
    size_t row = (size_t)y * W, plane = (size_t)W * H;
    floatv r = lum16v_row(G + row, x, W);
    floatv g = lum16v_row(G + plane + row, x, W);
    floatv b = lum16v_row(G + 2 * plane + row, x, W);
    floatv rc = CLAMP(loadv_row(rho_full + row, x, W), 0.0f, 1.0f);
    floatv yp = dotv(P->w_P, r, g, b), ys = dotv(P->w_S_tone, r, g, b);
    floatv I = rc * yp + (1.0f - rc) * ys;                              // Purkinje (Eq. 13)
    floatv R = tonev_shown(P, ln_sigma_n_of(P, A[0]), I);               // Eq. 1
    floatv ratio = R * rc / MAX(yp, P->Y_min), grey = R * (1.0f - rc);  // hue shift
    J.r = ratio * r + grey * P->k_s[0];
    J.g = ratio * g + grey * P->k_s[1];
    J.b = ratio * b + grey * P->k_s[2];
    return J;
}

// A map's value at the VEC lanes' positions from columns c0 .. c0 + VEC - 1 of rows ra and rb,
// when the lanes are less than a column apart (o: each lane's first column, from c0): the two
// rows mixed by ty's weights as one vector, then each lane takes its two columns of it.
HOT floatv map_at(__global const float *ra, __global const float *rb, int c0, lerp1_t ty,
                  intv o, lerpv_t tx) {
    floatv cols = ty.wa * LOADV_G(ra + c0) + ty.wb * LOADV_G(rb + c0);
    return tx.wa * lanes_at(cols, o) + tx.wb * lanes_at(cols, o + 1);
}

// Inlined into its three kernels: compose_rgb10 0.87-0.94× as long at VEC 16, 0.90-0.93× at 8,
// 0.94-0.97× built for znver3 (AVX2), against a call (docs/performance.md, "Compose").
HOT rgbv_t composev(__constant const params_t *P, __global const ushort *G,
                       __global const float *rho_full, __global const float *maps,
                       __global const float *A, int W, int H, int cell, int grid_w, int grid_h,
                       float gx, float gy, float eyes, __global const float *fovea, int x,
                       int y) {
    rgbv_t J0 = basev(P, G, rho_full, A, W, H, eyes, x, y);
    rgbv_t lms = matv_mul(P->rgb2lms, J0.r, J0.g, J0.b);
    // Afterimage maps at the retinal position of this pixel; off the grid: equilibrium.
    floatv px = (float)x + 0.5f + LANE_F;
    float py = y + 0.5f;
    lerpv_t tx = lerpv_at(grid_w, (px - gx) / cell + 0.5f * grid_w, 0);
    lerp1_t ty = lerp1_at(grid_h, (py - gy) / cell + 0.5f * grid_h, 0);
    int gp = grid_w * grid_h;
    floatv m0, m1, m2, m3, m4, m5;
    intv o = tx.x0 - tx.x0.s0;
    int c0 = tx.x0.s0;
    if (LAST(o) <= VEC - 2 && c0 >= 0 && c0 + VEC - 1 < grid_w) {
        // The VEC positions are less than a column apart (cell >= 2 at VEC 16; 1280x720 has
        // cell 4): columns c0 .. c0 + VEC - 1 serve them. 0.8× the time of compose_rgb10 with
        // a broadcast FMA per column at VEC 16 (docs/performance.md, "Compose").
        __global const float *ra = maps + ty.a * grid_w, *rb = maps + ty.b * grid_w;
        floatv w_out = 1.0f - (ty.wa + ty.wb) * (tx.wa + tx.wb);  // off the grid: equilibrium
#define MIX(c) map_at(ra + (c) * gp, rb + (c) * gp, c0, ty, o, tx)
        m0 = MIX(0) + w_out;
        m1 = MIX(1) + w_out;
        m2 = MIX(2) + w_out;
        m3 = MIX(3);
        m4 = MIX(4);
        m5 = MIX(5);
#undef MIX
    } else {
        m0 = bilinearv_get(maps, grid_w, tx, ty, 1.0f);
        m1 = bilinearv_get(maps + gp, grid_w, tx, ty, 1.0f);
        m2 = bilinearv_get(maps + 2 * gp, grid_w, tx, ty, 1.0f);
        m3 = bilinearv_get(maps + 3 * gp, grid_w, tx, ty, 0.0f);
        m4 = bilinearv_get(maps + 4 * gp, grid_w, tx, ty, 0.0f);
        m5 = bilinearv_get(maps + 5 * gp, grid_w, tx, ty, 0.0f);
    }
    floatv f = loadv_row(fovea, x, W) * fovea[W + y];  // foveal fall-off, separable
    lms.r *= 1.0f + f * (m0 - 1.0f);  // Eq. 12, alpha^j2 R
    lms.g *= 1.0f + f * (m1 - 1.0f);
    lms.b *= 1.0f + f * (m2 - 1.0f);
    rgbv_t J = matv_mul(P->lms2rgb, lms.r, lms.g, lms.b);
    J.r += f * m3;  // additive afterimage, linear RGB (Eq. 12: H times the bleaching term)
    J.g += f * m4;
    J.b += f * m5;
    // Gamut (reference.gamut_map): toward the grey of luminance min(Y, Y_c), Y_c that of the
    // hue's cusp, just far enough to fit; bright colours trade luminance for saturation. Where
    // all VEC pixels are inside the cube already (t = 1: the usual case), nothing moves.
    intv inside = J.r >= 0.0f && J.r <= 1.0f && J.g >= 0.0f && J.g <= 1.0f && J.b >= 0.0f &&
                  J.b <= 1.0f;
    if (anyv(~inside)) {
        floatv Y = dotv(P->w_P, J.r, J.g, J.b);
        floatv dr = J.r - Y, dg = J.g - Y, db = J.b - Y;
        floatv d_min = MIN(MIN(dr, dg), db), spread = MAX(MAX(dr, dg), db) - d_min;
        floatv a = MIN(CLAMP(Y, 0.0f, 1.0f), CLAMP(-d_min / MAX(spread, FLT_MIN), 0.0f, 1.0f));
        floatv er = J.r - a, eg = J.g - a, eb = J.b - a;
        floatv t = MAX(gamut_t(a, eb, gamut_t(a, eg, gamut_t(a, er, (floatv)(1.0f)))), 0.0f);
        J.r = inside ? J.r : CLAMP(a + t * er, 0.0f, 1.0f);
        J.g = inside ? J.g : CLAMP(a + t * eg, 0.0f, 1.0f);
        J.b = inside ? J.b : CLAMP(a + t * eb, 0.0f, 1.0f);
    }
    rgbv_t out;
    out.r = gammav(P, J.r);
    out.g = gammav(P, J.g);
    out.b = gammav(P, J.b);
    return out;
}

// 8 pixels of planar r, g, b: a half of an rgbv_t at VEC 16, all of it at VEC 8.
typedef struct {
    float8 r, g, b;
} rgb8_t;

HOT rgb8_t rgb_half(rgbv_t c, int h) {
#if VEC == 16
    rgb8_t o = {h ? c.r.hi : c.r.lo, h ? c.g.hi : c.g.lo, h ? c.b.hi : c.b.lo};
#else
    rgb8_t o = {c.r, c.g, c.b};
#endif
    return o;
}

// Interleave 8 pixels of planar r, g, b into rgbrgb... as three float8.
#define INTERLEAVE(o, c)                                                                    \
    float8 o##0 = (float8)(c.r.s0, c.g.s0, c.b.s0, c.r.s1, c.g.s1, c.b.s1, c.r.s2, c.g.s2); \
    float8 o##1 = (float8)(c.b.s2, c.r.s3, c.g.s3, c.b.s3, c.r.s4, c.g.s4, c.b.s4, c.r.s5); \
    float8 o##2 = (float8)(c.g.s5, c.b.s5, c.r.s6, c.g.s6, c.b.s6, c.r.s7, c.g.s7, c.b.s7);

// The first n (<= 8) of 8 pixels, interleaved, at o.
HOT void store_rgb8(__global float *o, rgb8_t c, int n) {
    INTERLEAVE(q, c)
    if (n >= 8) {
        STORE8_G(o, q0);
        STORE8_G(o + 8, q1);
        STORE8_G(o + 16, q2);
        return;
    }
    n *= 3;
    store8_part(o, q0, MIN(n, 8));
    if (n > 8) store8_part(o + 8, q1, MIN(n - 8, 8));
    if (n > 16) store8_part(o + 16, q2, n - 16);
}

// The same as IEEE half floats (round to nearest even).
HOT void store_half_rgb8(__global half *o, rgb8_t c, int n) {
    INTERLEAVE(q, c)
    if (n >= 8) {
        vstore_half8_rte(q0, 0, o);
        vstore_half8_rte(q1, 0, o + 8);
        vstore_half8_rte(q2, 0, o + 16);
        return;
    }
    float tmp[24];
    vstore8(q0, 0, tmp);
    vstore8(q1, 0, tmp + 8);
    vstore8(q2, 0, tmp + 16);
    for (int i = 0; i < 3 * n; ++i) vstore_half_rte(tmp[i], i, o);
}

#define COMPOSE_ARGS                                                                             \
    __constant const params_t *P, __global const ushort *G, __global const float *rho_full,     \
        __global const float *maps, __global const float *A, int W, int H, int cell, int grid_w, \
        int grid_h, float gx, float gy, float eyes, __global const float *fovea

#define COMPOSE_CALL P, G, rho_full, maps, A, W, H, cell, grid_w, grid_h, gx, gy, eyes, fovea

// The VEC pixels of c at pixel (x, y) of an H×W×3 interleaved image v, 8 at a time by STORE8
// (store_rgb8 or store_half_rgb8), the row's end cut off.
#define STORE_RGBV(STORE8, v, c, W, x, y)                                       \
    for (int h = 0; h < VEC / 8 && (x) + 8 * h < (W); ++h)                      \
        STORE8((v) + 3 * ((size_t)(y) * (W) + (x)) + 24 * h, rgb_half(c, h), \
               (W) - (x) - 8 * h)

// compose's kernels make two runs of VEC pixels a work-item (global size (ceil(W / 2 VEC), H)),
// both inlined one after the other where the row has them: compose_rgb10 0.83× as long as with
// one run at 1920×1080 (docs/performance.md, "Compose"); the row's last pixels a run at a time.
// STORE(c, x) stores the run at x, cut off at the row's end.
#define COMPOSE_RUNS(STORE)                                  \
    int x = get_global_id(0) * 2 * VEC, y = get_global_id(1); \
    if (x + 2 * VEC <= W) {                                  \
        rgbv_t c0 = composev(COMPOSE_CALL, x, y);             \
        rgbv_t c1 = composev(COMPOSE_CALL, x + VEC, y);       \
        STORE(c0, x);                                        \
        STORE(c1, x + VEC);                                  \
        return;                                              \
    }                                                        \
    for (; x < W; x += VEC) {                                \
        rgbv_t c = composev(COMPOSE_CALL, x, y);              \
        STORE(c, x);                                         \
    }

// v: H×W×3 float32, interleaved.
__kernel void compose(COMPOSE_ARGS, __global float *v) {
#define STORE(c, x) STORE_RGBV(store_rgb8, v, c, W, x, y)
    COMPOSE_RUNS(STORE)
#undef STORE
}

// compose as half floats, for frames sent as float16.
__kernel void compose_half(COMPOSE_ARGS, __global half *v) {
#define STORE(c, x) STORE_RGBV(store_half_rgb8, v, c, W, x, y)
    COMPOSE_RUNS(STORE)
#undef STORE
}

#define HALF_MAX 65504.0f  // the largest finite half float

// The late gaze warp's base layer: basev's linear RGB as H×W×3 interleaved half floats. The viewer
// applies Eq. 12, gamut and gamma at the newest gaze (web/warp.js; reference.apply_afterimages).
__kernel void compose_base(__constant const params_t *P, __global const ushort *G,
                           __global const float *rho_full, __global const float *A, int W,
                           int H, float eyes, __global half *v) {
    int x = get_global_id(0) * VEC, y = get_global_id(1);
    if (x >= W) return;
    rgbv_t J = basev(P, G, rho_full, A, W, H, eyes, x, y);
    J.r = MIN(J.r, HALF_MAX);  // J >= 0; a half float never Inf
    J.g = MIN(J.g, HALF_MAX);
    J.b = MIN(J.b, HALF_MAX);
    STORE_RGBV(store_half_rgb8, v, J, W, x, y);
}

// The same packed as WebGL2's RGB10_A2 takes it: round(1023 v) per channel (to nearest even),
// r | g << 10 | b << 20, alpha bits 0. One uint per pixel.
HOT void store_rgb10(__global uint *v, rgbv_t c, int W, int x, int y) {
#define TO_10BIT(v) CAT(CAT(convert_uint, VEC), _rte)((v) * 1023.0f)
    uintv q = TO_10BIT(c.r) | (TO_10BIT(c.g) << 10) | (TO_10BIT(c.b) << 20);
#undef TO_10BIT
    __global uint *o = v + (size_t)y * W + x;
    if (x + VEC <= W) {
        STOREV_UI(o, q);
        return;
    }
    uint tmp[VEC];
    STOREV_PRIVATE(q, tmp);
    for (int i = 0; i < W - x; ++i) o[i] = tmp[i];
}

__kernel void compose_rgb10(COMPOSE_ARGS, __global uint *v) {
#define STORE(c, x) store_rgb10(v, c, W, x, y)
    COMPOSE_RUNS(STORE)
#undef STORE
}

// The late gaze warp's maps for the viewer (gazehdr.warp): from the planar maps, gain - 1 then
// the additive term, each grid_h×grid_w×3 interleaved half floats (one RGB texture). Gain - 1:
// a small gain keeps half floats' 11 significant bits; within +-HALF_MAX: never an Inf. One
// work-item per cell.
__kernel void warp_maps(__global const float *maps, int grid_w, int grid_h, __global half *out) {
    int j = get_global_id(0), i = get_global_id(1);
    if (j >= grid_w || i >= grid_h) return;
    size_t gp = (size_t)grid_w * grid_h, at = (size_t)i * grid_w + j;
    for (int c = 0; c < 3; ++c) {
        vstore_half_rte(CLAMP(maps[c * gp + at] - 1.0f, -HALF_MAX, HALF_MAX), 3 * at + c, out);
        vstore_half_rte(CLAMP(maps[(3 + c) * gp + at], -HALF_MAX, HALF_MAX), 3 * (gp + at) + c,
                        out);
    }
}
