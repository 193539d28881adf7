// Mikamo et al. 2012, afterimages from Padgham's colour sequence (the `mikamo` baseline; the
// NumPy oracle is server/sim/baselines/mikamo.py, which says what each step means). One
// work-item per retina cell, global size (grid_w, grid_h): the grid is small and this stage
// is not the hot path, so correctness first.
//
// State planes: 0-2 the previous input L, M, S (I_on at the cell), 3 Z, 4-5 the latched
// (Delta a, Delta b) of Eq. 1, 6 age in seconds.
//
// consts: 0-8 RGB->XYZ, 9-17 XYZ->RGB, 18 X_n, 19 Z_n of the white (Y_n = 1), 20-21 (a*, b*)
// of the reference chromaticity at L* = 100, 22 the Delta E floor of Eq. 1, 23 the luminance
// below which the afterimage is black. seq: rows (t, L_M, a_M, b_M).

#define LAB_KNEE 0.008856451679f      // (6/29)^3
#define LAB_SLOPE 0.12841854934f      // 3 (6/29)^2
#define LAB_OFFSET 0.13793103448f     // 4/29

inline float lab_f1(float t) { return t > LAB_KNEE ? cbrt(t) : t / LAB_SLOPE + LAB_OFFSET; }

inline float lab_f_inv1(float f) {
    return f > 6.0f / 29.0f ? f * f * f : LAB_SLOPE * (f - LAB_OFFSET);
}

inline float3 mat3_mulc(__global const float *m, float3 v) {
    return (float3)(m[0] * v.x + m[1] * v.y + m[2] * v.z,
                    m[3] * v.x + m[4] * v.y + m[5] * v.z,
                    m[6] * v.x + m[7] * v.y + m[8] * v.z);
}

// Eq. 1: the input's colour against the reference at the same luminance, with the white
// scaled to that luminance (L* = 100); 0 below Y_min.
inline float2 delta_ab1(__global const float *k, float3 xyz, float Y_min) {
    if (!(xyz.y > Y_min)) return (float2)(0.0f);
    float fy = 1.0f;  // f(Y / Y) = f(1)
    float fx = lab_f1(xyz.x / (k[18] * xyz.y)), fz = lab_f1(xyz.z / (k[19] * xyz.y));
    float da = 500.0f * (fx - fy) - k[20], db = 200.0f * (fy - fz) - k[21];
    float norm = MAX(sqrt(da * da + db * db), k[22]);
    return (float2)(da, db) / norm;
}

__kernel void mikamo_step(__constant const params_t *P, __global const float *down,
                          __global const float *surround, __global float *state,
                          __global float *maps, __global float *add,
                          __global const float *k, __global const float4 *seq, int n_seq,
                          int low_w, int low_h, int cell, int grid_w, int grid_h, float gx,
                          float gy, float dt, int reset, float thr, float y_max, float drop,
                          float gamma, float strength) {
    int j = get_global_id(0), i = get_global_id(1);
    if (j >= grid_w || i >= grid_h) return;
    int plane = grid_w * grid_h, at = i * grid_w + j;
    // The scene at gaze + retinal offset, the surround off the screen (reference.retina_input).
    float3 lms = retina_lms1(down, surround, low_w, low_h, gx, gy, cell, grid_w, grid_h, j, i);
    float yp = dot3(P->w_P, mat3_mul(P->lms2rgb, lms));

    float Z = 0.0f, age = 0.0f;
    float2 d_lat = (float2)(0.0f);
    if (!reset) {
        float3 lms_prev = (float3)(state[at], state[plane + at], state[2 * plane + at]);
        float3 rgb_prev = mat3_mul(P->lms2rgb, lms_prev);
        float y_prev = dot3(P->w_P, rgb_prev);
        age = state[6 * plane + at] + dt;
        if (age <= seq[n_seq - 1].x) {  // still within the sequence; else the cell clears
            Z = state[3 * plane + at];
            d_lat = (float2)(state[4 * plane + at], state[5 * plane + at]);
        } else {
            age = 0.0f;
        }
        if (y_prev >= thr && MAX(y_prev, P->Y_min) >= drop * MAX(yp, P->Y_min)) {
            // Z = (L*_on / L*_on_max)^gamma, I_on's brightest cell as the white (Eq. 2-4)
            float L = y_max > 0.0f ? 116.0f * lab_f1(y_prev / y_max) - 16.0f : 0.0f;
            L = CLAMP(L, 0.0f, 100.0f);
            Z = L > 0.0f ? exp(gamma * log(L / 100.0f)) : 0.0f;
            d_lat = delta_ab1(k, mat3_mulc(k, rgb_prev), P->Y_min);
            age = 0.0f;
        }
    }
    float st[7] = {lms.x, lms.y, lms.z, Z, d_lat.x, d_lat.y, age};
    for (int c = 0; c < 7; ++c) state[c * plane + at] = st[c];
    maps[at] = 1.0f;
    maps[plane + at] = 1.0f;
    maps[2 * plane + at] = 1.0f;
    if (Z == 0.0f && d_lat.x == 0.0f && d_lat.y == 0.0f) {  // no afterimage: exactly 0
        add[at] = add[plane + at] = add[2 * plane + at] = 0.0f;
        return;
    }

    // Eq. 2-4 at this age: the sequence interpolated linearly between its rows.
    int r = 0;
    while (r < n_seq - 2 && age > seq[r + 1].x) ++r;
    float4 s0 = seq[r], s1 = seq[r + 1];
    float f = CLAMP((age - s0.x) / (s1.x - s0.x), 0.0f, 1.0f);
    float4 m = s0 + f * (s1 - s0);
    float tau = m.y / seq[0].y;  // tau_M = L_M / L_M(0); L_M(0) > 0 (checked on load)
    float L_A = m.y * Z, a_A = m.z * Z + tau * d_lat.x, b_A = m.w * Z + tau * d_lat.y;
    float fy = (L_A + 16.0f) / 116.0f;
    float3 xyz = (float3)(k[18] * lab_f_inv1(fy + a_A / 500.0f), lab_f_inv1(fy),
                          k[19] * lab_f_inv1(fy - b_A / 200.0f));
    // Gamut fix: clamp negatives, then restore the luminance at the clamped chromaticity.
    float3 c = MAX(mat3_mulc(k + 9, xyz), (float3)(0.0f));
    float Yc = k[3] * c.x + k[4] * c.y + k[5] * c.z;
    c *= Yc > k[23] ? strength * MAX(xyz.y, 0.0f) / Yc : 0.0f;
    add[at] = c.x;
    add[plane + at] = c.y;
    add[2 * plane + at] = c.z;
}
