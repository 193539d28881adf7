// Sec. 2.3, mesopic rendering: the local rho (Eq. 13) and the stochastic acuity loss (Eq. 14-15).
// The low-res maps made here also feed the adaptation and afterimage stages.

// cell×cell block averages of the (eyes-gated) scene: L, M, S, Y_P, Y_S planes.
__kernel void downsample(__constant const params_t *P, __global const float *scene,
                         __global float *down, int W, int H, int cell, int low_w, int low_h,
                         float eyes) {
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= low_w) return;
    int plane = W * H;
    float3 acc = (float3)(0.0f);
    int xe = min((x + 1) * cell, W), ye = min((y + 1) * cell, H);
    for (int yy = y * cell; yy < ye; ++yy)
        for (int xx = x * cell; xx < xe; ++xx) acc += load3(scene, plane, yy * W + xx);
    float3 rgb = eyes * acc / (float)((xe - x * cell) * (ye - y * cell));
    float3 lms = mat3_mul(P->rgb2lms, rgb);
    int lp = low_w * low_h, k = y * low_w + x;
    down[k] = lms.x; down[lp + k] = lms.y; down[2 * lp + k] = lms.z;
    down[3 * lp + k] = dot3(P->w_P, rgb);
    down[4 * lp + k] = dot3(P->w_S, rgb);
}

// Eq. 13, unclamped, from the blurred photopic luminance.
__kernel void rho_map(__constant const params_t *P, __global const float *yp_blurred,
                      __global float *rho, int n) {
    int k = get_global_id(0);
    if (k >= n) return;
    rho[k] = (log10(fmax(yp_blurred[k], P->Y_min)) - P->m2) / (P->m1 - P->m2);
}

// Eq. 15 with one noise field for all bands: d = number of finest bands dropped. The kept bands
// telescope (Eq. 14), so the result is Gaussian level d - 1 (level -1 is the scene itself).
// X is interpolated in space and time and renormalised so that it stays N(0, 1).
__kernel void acuity_levels(__constant const params_t *P, __global const float *rho,
                            __global const float *key0, __global const float *key1, float frac,
                            float spacing, int nx, int low_w, int low_h, int cell, int W, int H,
                            __global const float *scene, __global float *G,
                            __global uchar *d_map, volatile __global int *d_max) {
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= W) return;
    float px = x + 0.5f, py = y + 0.5f;
    float r = sample_plane(rho, low_w, low_h, px / cell, py / cell, 1, 0.0f);
    float u = px / spacing, v = py / spacing;
    float fu = floor(u), fv = floor(v);
    int i0 = (int)fu, j0 = (int)fv;
    float fx = u - fu, fy = v - fv;
    int k00 = j0 * nx + i0, k10 = k00 + 1, k01 = k00 + nx, k11 = k01 + 1;
    float s0 = (1 - fy) * ((1 - fx) * key0[k00] + fx * key0[k10]) + fy * ((1 - fx) * key0[k01] + fx * key0[k11]);
    float s1 = (1 - fy) * ((1 - fx) * key1[k00] + fx * key1[k10]) + fy * ((1 - fx) * key1[k01] + fx * key1[k11]);
    float norm = sqrt(((1 - fx) * (1 - fx) + fx * fx) * ((1 - fy) * (1 - fy) + fy * fy)
                      * ((1 - frac) * (1 - frac) + frac * frac));
    float q = r + P->g * ((1 - frac) * s0 + frac * s1) / norm;
    int d = 0;
    for (int b = 0; b < P->bands; ++b) d += (q <= P->rho_i[b]);
    int k = y * W + x, plane = W * H;
    d_map[k] = (uchar)d;
    if (d == 0) {
        G[k] = scene[k]; G[plane + k] = scene[plane + k]; G[2 * plane + k] = scene[2 * plane + k];
    } else {
        atomic_max(d_max, d);
    }
}
