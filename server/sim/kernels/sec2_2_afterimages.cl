// Sec. 2.2, afterimages: bleaching (Eq. 4-6) and calcium (Eq. 8-11) per cone on the retina
// grid, which is centred on the gaze and spans twice the screen. Calcium is stored normalised,
// c = C / C_max, so c_inf = 1 - R (Eq. 10 over C_max).

// Cone input at a retina cell: the low-res scene at gaze + offset; the room off screen is dark.
inline float3 retina_input(__global const float *down, int low_w, int low_h, int cell,
                           int grid_w, int grid_h, float gx, float gy, int j, int i) {
    float sx = (gx + (j + 0.5f - 0.5f * grid_w) * cell) / cell;
    float sy = (gy + (i + 0.5f - 0.5f * grid_h) * cell) / cell;
    int plane = low_w * low_h;
    bilinear_t t = bilinear_at(low_w, low_h, sx, sy, 0);
    return (float3)(bilinear_get(down, t, 0.0f), bilinear_get(down + plane, t, 0.0f),
                    bilinear_get(down + 2 * plane, t, 0.0f));
}

inline float3 bleach_inf(__constant const params_t *P, float3 I) {
    float3 b1I = (float3)(P->b1[0], P->b1[1], P->b1[2]) * I;
    return b1I / (b1I + (float3)(P->b2[0], P->b2[1], P->b2[2]));  // Eq. 6
}

inline float3 calcium_inf(__constant const params_t *P, float lsn, float3 I) {
    return (float3)(1.0f - tone(P, lsn, I.x), 1.0f - tone(P, lsn, I.y), 1.0f - tone(P, lsn, I.z));
}

// One time step of the state; with reset, the equilibrium for the current input.
__kernel void retina_update(__constant const params_t *P, __global const float *down,
                            __global const float *state, __global float *out,
                            __global const float *A, int low_w, int low_h, int cell, int grid_w,
                            int grid_h, float gx, float gy, float dt, int reset) {
    int j = get_global_id(0), i = get_global_id(1);
    if (j >= grid_w) return;
    int plane = grid_w * grid_h, k = i * grid_w + j;
    float3 I = retina_input(down, low_w, low_h, cell, grid_w, grid_h, gx, gy, j, i);
    float lsn = ln_sigma_n_of(P, A[0]);
    float3 B_inf = bleach_inf(P, I);
    float3 c_inf = calcium_inf(P, lsn, I);
    float3 B = B_inf, c = c_inf;
    if (!reset) {
        float3 rate = (float3)(P->b1[0], P->b1[1], P->b1[2]) * I
                      + (float3)(P->b2[0], P->b2[1], P->b2[2]);
        B = (load3(state, plane, k) - B_inf) * exp(-rate * dt) + B_inf;  // Eq. 5
        c = (load3(state + 3 * plane, plane, k) - c_inf) * exp(-P->c2 * dt) + c_inf;  // Eq. 9
        B = clamp(B, 0.0f, 1.0f);
        c = clamp(c, 0.0f, 1.0f);
    }
    out[k] = B.x; out[plane + k] = B.y; out[2 * plane + k] = B.z;
    out[3 * plane + k] = c.x; out[4 * plane + k] = c.y; out[5 * plane + k] = c.z;
}

// Gain alpha^j2 (Eq. 11, guarded by alpha_eps so darkness gives 1, not 0/0) and the
// bleaching term j1 c max(B - B_inf, 0) of Eq. 12, per cone, from the blurred state.
__kernel void afterimage_maps(__constant const params_t *P, __global const float *down,
                              __global const float *state, __global float *maps,
                              __global const float *A, int low_w, int low_h, int cell,
                              int grid_w, int grid_h, float gx, float gy) {
    int j = get_global_id(0), i = get_global_id(1);
    if (j >= grid_w) return;
    int plane = grid_w * grid_h, k = i * grid_w + j;
    float3 I = retina_input(down, low_w, low_h, cell, grid_w, grid_h, gx, gy, j, i);
    float lsn = ln_sigma_n_of(P, A[0]);
    float3 B = load3(state, plane, k), c = load3(state + 3 * plane, plane, k);
    float3 alpha = (1.0f - calcium_inf(P, lsn, I) + P->alpha_eps) / (1.0f - c + P->alpha_eps);
    float3 gain = pow_pos(alpha, P->j2);
    float3 bleach = P->j1 * c * fmax(B - bleach_inf(P, I), 0.0f);
    maps[k] = gain.x; maps[plane + k] = gain.y; maps[2 * plane + k] = gain.z;
    maps[3 * plane + k] = bleach.x; maps[4 * plane + k] = bleach.y; maps[5 * plane + k] = bleach.z;
}
