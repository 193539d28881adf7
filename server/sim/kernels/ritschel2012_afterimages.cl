// Ritschel & Eisemann 2012, afterimages as a baseline (server/sim/baselines/ritschel.py is the
// reference this mirrors). State r (L, M, S planes) on the retina grid, which is centred on the
// gaze and spans twice the screen. The input and the kinetics are light, one work-item per
// cell; the maps are the cost (about half of it the oRGB trigonometry), VEC cells per work-item.

// L of Eq. 3 before the micro-saccade blur: the low-res cone input at gaze + retinal offset
// (bilinear, the surround off the screen) over L_ref. Global size (grid_w, grid_h).
__kernel void ritschel_input(__global const float *down, __global const float *surround,
                             __global float *L, int low_w, int low_h, int cell, int grid_w,
                             int grid_h, float gx, float gy, float inv_L_ref) {
    int j = get_global_id(0), i = get_global_id(1);
    if (j >= grid_w || i >= grid_h) return;
    float3 v = inv_L_ref *
               retina_lms1(down, surround, low_w, low_h, gx, gy, cell, grid_w, grid_h, j, i);
    int cells = grid_w * grid_h, at = i * grid_w + j;
    L[at] = v.x;
    L[cells + at] = v.y;
    L[2 * cells + at] = v.z;
}

// Equilibrium of Eq. 3 for a constant input, r_inf = c_a L / (c_a L + c_d), of a = c_a L
// (guarded: c_d = 0 in darkness would be 0/0).
#define R_INF(a, c_d) ((a) / MAX((a) + (c_d), 1e-30f))

// One clamped explicit step of Eq. 3 (Listing 1) of length h, or with reset the equilibrium.
// r_in and r_out may be the same buffer. Global size (3 grid_w grid_h).
__kernel void ritschel_kinetics(__global const float *L, __global const float *r_in,
                                __global float *r_out, int n, float h, float c_a, float c_d,
                                int reset) {
    int k = get_global_id(0);
    if (k >= n) return;
    float r;
    if (reset) {
        r = R_INF(c_a * L[k], c_d);
    } else {
        r = r_in[k];
        r = CLAMP(r + h * (c_a * L[k] * (1.0f - r) - c_d * r), 0.0f, 1.0f);
    }
    r_out[k] = r;
}

// The maps run on the whole grid every frame and need powers, atan2, cos and sin per cell: as
// floatv with inline polynomials (PoCL's builtins are calls, see common.cl), VEC cells per
// work-item. Global size (ceil(grid_w grid_h / VEC)).

#define ABSV(x) MAX(x, -(x))

// atan2(y, x) in [-pi, pi], 0 at the origin: Cephes' atanf (S. L. Moshier) on min/max of
// |x|, |y| in [0, 1], reduced by pi/4 above tan(pi/8); within a few ulp.
inline floatv atan2_v(floatv y, floatv x) {
    floatv ax = ABSV(x), ay = ABSV(y);
    floatv a = MIN(ax, ay) / MAX(MAX(ax, ay), FLT_MIN);
    intv big = a > 0.4142135623730950f;
    floatv z = big ? (a - 1.0f) / (a + 1.0f) : a;
    floatv z2 = z * z;
    floatv p = ((8.05374449538e-2f * z2 - 1.38776856032e-1f) * z2 + 1.99777106478e-1f) * z2;
    p = (p - 3.33329491539e-1f) * z2 * z + z;
    floatv t = big ? p + M_PI_4_F : p;
    t = ay > ax ? M_PI_2_F - t : t;
    t = x < 0.0f ? M_PI_F - t : t;
    return y < 0.0f ? -t : t;
}

// cos and sin of t in [-2 pi, 2 pi]: Cephes' sinf/cosf, reduced to octants.
inline void sincosv(floatv t, floatv *c, floatv *s) {
    floatv x = ABSV(t);
    intv j = TO_INTV(x * 1.27323954473516f);  // 4 / pi
    j = (j + 1) & ~1;
    floatv fj = TO_FLOATV(j);
    x = ((x - fj * 0.78515625f) - fj * 2.4187564849853515625e-4f) - fj * 3.77489497744594108e-8f;
    floatv z = x * x;
    floatv ps = ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * x + x;
    floatv pc = ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z +
                 4.166664568298827e-2f) * z * z - 0.5f * z + 1.0f;
    intv q = (j >> 1) & 3;  // quadrant
    intv swap = (q & 1) != 0;
    floatv sv = swap ? pc : ps, cv = swap ? ps : pc;
    sv = (q & 2) != 0 ? -sv : sv;
    cv = (q == 1 || q == 2) ? -cv : cv;
    *s = t < 0.0f ? -sv : sv;
    *c = cv;
}

// The oRGB hue map (Bratkova et al. 2009): |t| < pi/3 -> 3t/2, else pi/2 + 3(|t| - pi/3)/4,
// mirrored for negative angles (dir > 0); or its inverse.
inline floatv hue_mapv(floatv t, int dir) {
    floatv a = ABSV(t), m;
    if (dir > 0) m = a < M_PI_F / 3.0f ? 1.5f * a : M_PI_2_F + 0.75f * (a - M_PI_F / 3.0f);
    else m = a < M_PI_2_F ? a / 1.5f : M_PI_F / 3.0f + (a - M_PI_2_F) / 0.75f;
    return t < 0.0f ? -m : m;
}

// Chroma (c.g, c.b) turned so that its angle t becomes hue_mapv(t, dir); radius and c.r kept.
inline rgbv_t remap_huev(rgbv_t c, int dir) {
    floatv rho = sqrt(c.g * c.g + c.b * c.b);
    floatv t = hue_mapv(atan2_v(c.b, c.g), dir), ct, st;
    sincosv(t, &ct, &st);
    rgbv_t o = {c.r, rho * ct, rho * st};
    return o;
}

// maps[0:3] = 1 (no gain); maps[3:6] = strength × the opponent colour in oRGB (chroma negated,
// then turned by the flight-of-colours angle, cos_f / sin_f) of the bleaching in excess of the
// current input's equilibrium, as linear RGB >= 0: encoded as max(J, 0)^gamma, and brought
// into the gamut at the same luma and oRGB hue (R'G'B' - L' shrunk until no component is
// negative) before decoding. `orgb` holds the R'G'B' -> oRGB matrix (before the hue map), then
// its exact inverse.
__kernel void ritschel_maps(__constant const params_t *P, __constant const float *orgb,
                            __global const float *L, __global const float *r,
                            __global float *maps, int n, float c_a, float c_d, float strength,
                            float cos_f, float sin_f) {
    int k = get_global_id(0) * VEC;
    if (k >= n) return;
    floatv e[3];
    for (int c = 0; c < 3; ++c) {
        floatv r_inf = R_INF(c_a * loadv_row(L + c * n, k, n), c_d);
        e[c] = MAX(loadv_row(r + c * n, k, n) - r_inf, 0.0f);
    }
    rgbv_t x = matv_mul(P->lms2rgb, e[0], e[1], e[2]);
    float g = P->gamma;
    x = matv_mul(orgb, powv_pos(x.r, g), powv_pos(x.g, g), powv_pos(x.b, g));  // 0 below 0
    x = remap_huev(x, 1);
    rgbv_t o = {x.r, -(cos_f * x.g - sin_f * x.b), -(sin_f * x.g + cos_f * x.b)};
    o = remap_huev(o, -1);
    x = matv_mul(orgb + 9, o.r, o.g, o.b);
    // Into the gamut: the luma o.r >= 0 is kept, the chroma shrunk by s (the hue map keeps radii).
    floatv low = MIN(MIN(x.r, x.g), x.b);
    floatv s = low < 0.0f ? o.r / MAX(o.r - low, 1e-30f) : 1.0f;
    floatv add[3] = {x.r, x.g, x.b};
    int m = MIN(VEC, n - k);
    for (int c = 0; c < 3; ++c) {
        storev_part(maps + c * n + k, (floatv)(1.0f), m);
        add[c] = strength * powv_pos(o.r + s * (add[c] - o.r), 1.0f / g);
        storev_part(maps + (3 + c) * n + k, add[c], m);
    }
}
