// The acuity models Sec. 2.3.3 compares with (Fig. 12): the bilateral of Jensen et al. 2000 and
// the blur, edge band and temporal noise of Thompson et al. 2002. The uniform Gaussian of
// Ferwerda et al. 1996 uses blur_h / blur_v of common.cl. NumPy reference and readings:
// server/sim/baselines/acuity.py. One pixel per work-item (global size (W, H)) except the
// bilateral passes: these are baselines for comparison, correctness first.

// Bilateral guide and spatial sigma per pixel: log10 photopic luminance (floored at Y_min) and
// the Ferwerda sigma of the local luminance (Eq. 13 inverted), beyond the viewer's own at
// 10^A_min (s_disp2, deg^2), capped at s_max deg. fa..fd: the constants of R(L) (FERWERDA).
__kernel void bilateral_prep(__constant const params_t *P, __global const float *scene,
                             __global const float *rho_full, __global float *guide,
                             __global float *sigma, int W, int H, float fa, float fb, float fc, float fd, float k,
                             float s_disp2, float s_max, float ppd) {
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H) return;
    int i = y * W + x;
    guide[i] = log10(fmax(dot3(P->w_P, load3(scene, W * H, i)), P->Y_min));
    float logL = P->m2 + rho_full[i] * (P->m1 - P->m2);
    float R = fa * atan(fb * logL + fc) + fd;
    float s = k / fmax(R, k / s_max);
    sigma[i] = sqrt(fmax(s * s - s_disp2, 0.0f)) * ppd;
}

// One 1-D pass (dx, dy) = (1, 0) or (0, 1) of the separable bilateral: spatial Gaussian of the
// output pixel's sigma, range Gaussian on the guide; taps off the frame are left out.
// var_floor keeps 1/sigma^2 finite where sigma = 0 (the pass is then the identity). The inner
// loop is the cost (an exp per tap), so it makes VEC pixels of a row per work-item with expv
// (see common.cl). Global size (ceil(W / VEC), H).
__kernel void bilateral_pass(__global const float *src, __global float *dst,
                             __global const float *guide, __global const float *sigma, int W,
                             int H, int radius, int dx, int dy, float inv_r, float var_floor) {
    int x = get_global_id(0) * VEC, y = get_global_id(1);
    if (x >= W) return;
    size_t plane = (size_t)W * H, row = (size_t)y * W;
    floatv s = loadv_row(sigma + row, x, W);
    floatv inv_s = 0.5f / MAX(s * s, var_floor);
    floatv g0 = loadv_row(guide + row, x, W);
    floatv r = loadv_row(src + row, x, W);
    floatv g = loadv_row(src + plane + row, x, W);
    floatv b = loadv_row(src + 2 * plane + row, x, W);
    floatv wsum = 1.0f;
    for (int k = -radius; k <= radius; ++k) {
        int yq = y + k * dy;
        if (k == 0 || yq < 0 || yq >= H) continue;
        int x0 = x + k * dx;
        intv xq = x0 + LANE_I;
        size_t rq = (size_t)yq * W;
        floatv dl = row_tapsv(guide + rq, x0, W) - g0;
        floatv w = expv(-(float)(k * k) * inv_s - dl * dl * inv_r);
        w = (xq >= 0 && xq < W) ? w : 0.0f;
        r += w * row_tapsv(src + rq, x0, W);
        g += w * row_tapsv(src + plane + rq, x0, W);
        b += w * row_tapsv(src + 2 * plane + rq, x0, W);
        wsum += w;
    }
    int n = MIN(VEC, W - x);
    storev_part(dst + row + x, r / wsum, n);
    storev_part(dst + plane + row + x, g / wsum, n);
    storev_part(dst + 2 * plane + row + x, b / wsum, n);
}

// Photopic luminance plane (Thompson's edge band is taken on luminance).
__kernel void luminance(__constant const params_t *P, __global const float *scene,
                        __global float *lum, int W, int H) {
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H) return;
    int i = y * W + x;
    lum[i] = dot3(P->w_P, load3(scene, W * H, i));
}

// C. Wellons' lowbias32, as web/renderer.js and the NumPy reference.
inline uint lowbias32(uint x) {
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

// Thompson et al.: ln Y' = ln Yb + gain (ln Yb - ln Ys) on the blurred luminance Yb with Ys
// blurred thompson_dog_ratio times wider; the blurred colour ratios kept; then the factor
// 1 + amp (1 - rho_c) N, N ~ N(0,1) from (key, pixel) by lowbias32 and Box-Muller.
__kernel void thompson_combine(__constant const params_t *P, __global const float *blurred,
                               __global const float *lum_wide, __global const float *rho_full,
                               __global float *G, int W, int H, float gain, float amp, uint key) {
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H) return;
    int plane = W * H, i = y * W + x;
    float3 rgb = load3(blurred, plane, i);
    float yb = fmax(dot3(P->w_P, rgb), P->Y_min);
    float edge = exp(gain * (log(yb) - log(fmax(lum_wide[i], P->Y_min))));
    uint h = lowbias32(key ^ lowbias32((uint)i));
    float u1 = ((float)(h >> 8) + 0.5f) * (1.0f / 16777216.0f);
    float u2 = (float)(lowbias32(h + 0x9e3779b9u) >> 8) * (1.0f / 16777216.0f);
    float n = sqrt(-2.0f * log(u1)) * cospi(2.0f * u2);
    float rho_c = clamp(rho_full[i], 0.0f, 1.0f);
    float f = edge * fmax(1.0f + amp * (1.0f - rho_c) * n, 0.0f);
    G[i] = f * rgb.x;
    G[plane + i] = f * rgb.y;
    G[2 * plane + i] = f * rgb.z;
}
