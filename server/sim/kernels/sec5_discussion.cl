// Sec. 5, observations the paper leaves for future work, off by default (Params).
// The afterimage boost after a blink or a saccade is a scalar on the foveal fall-off
// (OpenCLBackend.compose); what is here is the scotopic foveal blind spot.

// The rod-free fovea in scotopic light: G filled in with `fill` (reference.fill_map: L, M, S,
// here to RGB) by w = w_xy[x] w_xy[W + y] (1 - rho_c), a separable Gaussian around the gaze
// that the host scales by the strength the tracker allows (layout.blind_spot_strength).
// Global size (ceil(W / VEC), H).
__kernel void foveal_blind_spot(__constant const params_t *P, __global ushort *G,
                                __global const float *rho_full, __global const float *fill,
                                __global const float *w_xy, int W, int H, int cell, int low_w,
                                int low_h) {
    int x = get_global_id(0) * VEC, y = get_global_id(1);
    if (x >= W) return;
    size_t row = (size_t)y * W, plane = (size_t)W * H;
    floatv rc = CLAMP(loadv_row(rho_full + row, x, W), 0.0f, 1.0f);
    floatv w = loadv_row(w_xy, x, W) * w_xy[W + y] * (1.0f - rc);
    lerpv_t tx = lerpv_at(low_w, ((float)x + 0.5f + LANE_F) / cell, 1);
    lerp1_t ty = lerp1_at(low_h, (y + 0.5f) / cell, 1);
    int lp = low_w * low_h;
    rgbv_t rgb = matv_mul(P->lms2rgb, bilinearv_get(fill, low_w, tx, ty, 0.0f),
                          bilinearv_get(fill + lp, low_w, tx, ty, 0.0f),
                          bilinearv_get(fill + 2 * lp, low_w, tx, ty, 0.0f));
    floatv f[3] = {MAX(rgb.r, 0.0f), MAX(rgb.g, 0.0f), MAX(rgb.b, 0.0f)};  // as the reference
    for (int c = 0; c < 3; ++c) {
        __global ushort *g = G + c * plane + row;
        floatv v = lum16v_row(g, x, W);
        lum16v_store(g + x, v + w * (f[c] - v), W - x);
    }
}
