// Sec. 2.1, global adaptation: the target A_T around the gaze and the update of A (Eq. 3).
// One work-group sums the Gaussian-weighted mesopic luminance over the low-res window; its
// first work-item then moves A, so A never leaves the device between frames.

#define ADAPT_WG 256

__kernel __attribute__((reqd_work_group_size(ADAPT_WG, 1, 1)))
void adapt(__constant const params_t *P, __global const float *down, __global const float *rho,
           __global float *A, int low_w, int low_h, int cell, float cx, float cy, float sigma,
           int x0, int x1, int y0, int y1, float dt, int reset) {
    __local float sum_wy[ADAPT_WG];
    __local float sum_w[ADAPT_WG];
    int lid = get_local_id(0);
    int plane = low_w * low_h;
    int ww = x1 - x0 + 1, count = ww * (y1 - y0 + 1);
    float inv2s2 = 1.0f / (2.0f * sigma * sigma);
    float acc_wy = 0.0f, acc_w = 0.0f;
    for (int k = lid; k < count; k += ADAPT_WG) {
        int x = x0 + k % ww, y = y0 + k / ww, i = y * low_w + x;
        float dx = (x + 0.5f) * cell - cx, dy = (y + 0.5f) * cell - cy;
        float wgt = exp(-(dx * dx + dy * dy) * inv2s2);
        float rc = clamp(rho[i], 0.0f, 1.0f);
        float ymes = rc * down[3 * plane + i] + (1.0f - rc) * down[4 * plane + i];  // Eq. 13 blend
        acc_wy += wgt * ymes;
        acc_w += wgt;
    }
    sum_wy[lid] = acc_wy;
    sum_w[lid] = acc_w;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int s = ADAPT_WG / 2; s > 0; s >>= 1) {
        if (lid < s) {
            sum_wy[lid] += sum_wy[lid + s];
            sum_w[lid] += sum_w[lid + s];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (lid == 0) {
        float mean = sum_wy[0] / fmax(sum_w[0], 1e-30f);
        float target = fmax(log10(fmax(mean, P->Y_min)), P->A_min);  // floor of Sec. 2.4
        float a = A[0];
        if (reset) a = target;
        else if (a < target) a = fmin(a + P->a1 * dt, target);  // Eq. 3, no overshoot
        else a = fmax(a - P->a2 * dt, target);
        A[0] = a;
    }
}
