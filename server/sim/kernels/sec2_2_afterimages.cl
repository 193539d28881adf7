// Sec. 2.2, afterimages: bleaching (Eq. 4-6) and calcium (Eq. 8-11) per cone on the retina
// grid, which is centred on the gaze and spans twice the screen. Calcium is stored normalised,
// c = C / C_max, so c_inf = 1 - R (Eq. 10 over C_max). The state's planes: B (3), c (3), x (3),
// the light each cone is adapted to over sigma (ours: reference.adapted_light), relaxing in
// linear units at the calcium's rate; it gives the calcium gain its direction. One work-item makes VEC neighbouring
// cells of a grid row; global size (ceil(grid_w / VEC), grid_h), times the cones (retina_update)
// or the planes (retina_blur) it takes one at a time. Off the screen the retina reads the
// `surround` map (L, M, S planes of the low-res grid, made by surround_map below) at the
// nearest screen cell.
//
// One cone or one plane a work-item, not all nine planes: on PoCL a work-item that reads and
// writes nine planes keeps 18 and more memory streams going at once, more than the CPU's
// prefetchers follow (retina_update 0.84-0.89×, the map blur 0.45× so).

typedef struct {
    floatv l, m, s;
} conev_t;

// Taps x0 .. x0 + 7 of row y of one plane of the low-res scene `down`; a tap off the screen
// reads the `surround` map at the nearest screen cell.
HOT floatv input_tapsv(__global const float *down, __global const float *surround, int x0,
                          int y, int low_w, int low_h) {
    int row_in = y >= 0 && y < low_h, cols_in = x0 >= 0 && x0 + VEC <= low_w;
    if (row_in && cols_in) return LOADV_G(down + y * low_w + x0);
    __global const float *m = surround + CLAMP(y, 0, low_h - 1) * low_w;
    // Wholly left or right of the screen (most of the grid): one surround cell for all of them.
    if (x0 + VEC <= 0) return (floatv)(m[0]);
    if (x0 >= low_w) return (floatv)(m[low_w - 1]);
    intv x = x0 + LANE_I, xc = CLAMP(x, 0, low_w - 1);
    floatv s = cols_in ? LOADV_G(m + x0) : gatherv(m, xc);
    if (!row_in) return s;
    return (x >= 0 && x < low_w) ? gatherv(down + y * low_w, xc) : s;
}

// Cone c's input at VEC retina cells: the low-res scene at gaze + offset (bilinear), the surround
// off it. Neighbouring cells are whole low-res cells apart (same cell size), so the bilinear
// weights are the same for all of them and the taps are consecutive.
HOT floatv retina_input_conev(__global const float *down, __global const float *surround,
                              int low_w, int low_h, float gx, float gy, int cell, int grid_w,
                              int grid_h, int j, int i, int c) {
    float gxc = gx / cell, gyc = gy / cell;
    float fxc = floor1(gxc), fyc = floor1(gyc);
    float fx = gxc - fxc, fy = gyc - fyc;
    int x0 = (int)fxc + j - grid_w / 2, y0 = (int)fyc + i - grid_h / 2;
    int plane = low_w * low_h;
    __global const float *d = down + c * plane, *s = surround + c * plane;
    floatv top = (1.0f - fx) * input_tapsv(d, s, x0, y0, low_w, low_h) +
                 fx * input_tapsv(d, s, x0 + 1, y0, low_w, low_h);
    floatv bot = (1.0f - fx) * input_tapsv(d, s, x0, y0 + 1, low_w, low_h) +
                 fx * input_tapsv(d, s, x0 + 1, y0 + 1, low_w, low_h);
    return (1.0f - fy) * top + fy * bot;
}

// All three cones' input at VEC retina cells.
HOT conev_t retina_inputv(__global const float *down, __global const float *surround,
                          int low_w, int low_h, float gx, float gy, int cell, int grid_w,
                          int grid_h, int j, int i) {
#define CONE(c) \
    retina_input_conev(down, surround, low_w, low_h, gx, gy, cell, grid_w, grid_h, j, i, c)
    conev_t I = {CONE(0), CONE(1), CONE(2)};
#undef CONE
    return I;
}

// The surround map (reference.surround_map): at each of the frame's outermost low-res cells,
// P->surround times the Gaussian average of L, M, S along the edge, a closed loop of n cells
// (layout.edge_loop: edge_cell gives the cell of a loop position, edge_position the first
// position of a cell). Global size n.
HOT int2 edge_cell(int k, int w, int h) {
    int right = w - 1, bottom = (w - 1) + (h - 1), left = 2 * (w - 1) + (h - 1);
    if (k < right) return (int2)(k, 0);
    if (k < bottom) return (int2)(w - 1, k - right);
    if (k < left) return (int2)(w - 1 - (k - bottom), h - 1);
    return (int2)(0, h - 1 - (k - left));
}

HOT int edge_position(int2 c, int w, int h) {
    if (c.y == 0) return c.x;
    if (c.x == w - 1) return (w - 1) + c.y;
    if (c.y == h - 1) return (w - 1) + (h - 1) + (w - 1 - c.x);
    return 2 * (w - 1) + (h - 1) + (h - 1 - c.y);
}

__kernel void surround_map(__constant const params_t *P, __global const float *down,
                           __global float *surround, __constant const float *taps, int radius,
                           int n, int low_w, int low_h) {
    int k = get_global_id(0);
    if (k >= n) return;
    int2 at = edge_cell(k, low_w, low_h);
    if (edge_position(at, low_w, low_h) != k) return;  // met twice (a one-cell-wide frame)
    int plane = low_w * low_h;
    float3 acc = (float3)(0.0f);
    for (int t = -radius; t <= radius; ++t) {
        int2 c = edge_cell(((k + t) % n + n) % n, low_w, low_h);
        acc += taps[t + radius] * load3(down, plane, c.y * low_w + c.x);
    }
    int i = at.y * low_w + at.x;
    surround[i] = P->surround * acc.x;
    surround[plane + i] = P->surround * acc.y;
    surround[2 * plane + i] = P->surround * acc.z;
}

HOT floatv bleach_infv(__constant const params_t *P, int c, floatv I) {
    floatv b1I = P->b1[c] * I;
    return b1I / (b1I + P->b2[c]);  // Eq. 6
}

HOT floatv load_cellv(__global const float *p, int j, int n) { return loadv_row(p, j, n); }

// 1 / sigma of Eq. 2 (reference.adapted_light: x_inf = I / sigma), from ln sigma^n (expv on
// a splat: the scalar exp is a library call under PoCL).
HOT float inv_sigma(__constant const params_t *P, float lsn) {
    return expv((floatv)(-lsn / P->n)).s0;
}

HOT void store_cellv(__global float *p, floatv v, int j, int n) {
    if (j + VEC <= n) STOREV_G(p + j, v);
    else storev_part(p + j, v, n - j);
}

// One time step of cone c's three planes (B, c, x; c = get_global_id(2)); with reset, the
// equilibrium for the current input (s_inf; retina_settle_* make the fixed point of steps of dt
// from it). decay_c = exp(-c2 dt). Global size (ceil(grid_w / VEC), grid_h, 3).
__kernel void retina_update(__constant const params_t *P, __global const float *down,
                            __global const float *surround, __global const float *state,
                            __global float *out, __global const float *A, int low_w, int low_h,
                            int cell, int grid_w, int grid_h, float gx, float gy, float dt,
                            int reset, float decay_c) {
    int j = get_global_id(0) * VEC, i = get_global_id(1), c = get_global_id(2);
    if (j >= grid_w) return;
    int plane = grid_w * grid_h;
    size_t row = (size_t)i * grid_w;
    floatv In =
        retina_input_conev(down, surround, low_w, low_h, gx, gy, cell, grid_w, grid_h, j, i, c);
    float lsn = ln_sigma_n_of(P, A[0]), xs = inv_sigma(P, lsn);
    floatv B_inf = bleach_infv(P, c, In);
    floatv c_inf = 1.0f - tonev(P, lsn, In);
    floatv x_inf = In * xs;
    floatv B = B_inf, ca = c_inf, x = x_inf;
    if (!reset) {
        floatv rate = P->b1[c] * In + P->b2[c];
        B = (load_cellv(state + c * plane + row, j, grid_w) - B_inf) * expv(-rate * dt) + B_inf;
        ca = (load_cellv(state + (3 + c) * plane + row, j, grid_w) - c_inf) * decay_c + c_inf;
        x = (load_cellv(state + (6 + c) * plane + row, j, grid_w) - x_inf) * decay_c + x_inf;
        B = CLAMP(B, 0.0f, 1.0f);
        ca = CLAMP(ca, 0.0f, 1.0f);
        x = MAX(x, 0.0f);
    }
    store_cellv(out + c * plane + row, B, j, grid_w);
    store_cellv(out + (3 + c) * plane + row, ca, j, grid_w);
    store_cellv(out + (6 + c) * plane + row, x, j, grid_w);
}

// The cosine between the calcium's gain and -u below which the gain fades (reference.AGREE_COS).
#define AGREE_COS 0.5f

// The maps of VEC cells (reference.afterimage_maps). Gain: Eq. 11's alpha^j2 per cone (guarded by
// alpha_eps so darkness gives 1, not 0/0); with gain_along_adapting_light its length kept but
// pointed along -u, u the linear cone contrast of the light the eye adapted to (the state's x)
// against the light now, on the side of Eq. 11's vector and fading where the two are near
// right angles (ours: reference.opponent_gain, linear_contrast). Add: Eq. 12's bleaching term
// times the display gain (reference.bleach_term); with bleach_equivalent_light, as the cone's
// response to its equivalent light (ours: reference.bleach_response); to linear RGB through H.
// The maps are only shown (compose, the warp), never fed back: the gain's logs and exps are
// the display-precision ones (log_shownv, exp_shownv), within the maps' oracle tolerance.
inline void mapsv(__constant const params_t *P, __global const float *down,
                  __global const float *surround, floatv *st, __global float *maps, float lsn,
                  int low_w, int low_h, int cell, int grid_w, int grid_h, float gx, float gy,
                  int j, int i) {
    int plane = grid_w * grid_h;
    size_t row = (size_t)i * grid_w;
    conev_t I = retina_inputv(down, surround, low_w, low_h, gx, gy, cell, grid_w, grid_h, j, i);
    floatv In[3] = {I.l, I.m, I.s};
    floatv u[3], ln_gain[3], bleach[3];
    floatv len_g = 0.0f, u_max = 0.0f;
    float eps = P->alpha_eps, lsn_floor = ln_sigma_n_of(P, P->A_min), xs = inv_sigma(P, lsn);
    float floor_x = P->contrast_floor;
    for (int c = 0; c < 3; ++c) {
        floatv ca = st[3 + c], R_now = tonev_shown(P, lsn, In[c]);  // c_inf = 1 - R_now, Eq. 10
        floatv ln_now = log_shownv(R_now + eps), ln_then = log_shownv(1.0f - ca + eps);
        ln_gain[c] = P->j2 * (ln_now - ln_then);  // ln alpha^j2, Eq. 11
        floatv x_inf = In[c] * xs;
        u[c] = (st[6 + c] - x_inf) / MAX(x_inf, floor_x);  // reference.linear_contrast
        len_g += ln_gain[c] * ln_gain[c];
        u_max = MAX(u_max, ABSV(u[c]));
        // Eq. 12's bleaching term (reference.bleach_term)
        floatv x = P->bleach_display_gain * P->j1 * ca * MAX(st[c] - bleach_infv(P, c, In[c]), 0.0f);
        bleach[c] = x;
        if (!P->bleach_equivalent_light) continue;
        // ... as a response x; its light R^-1(x) at A_min adds to the input.
        x = MIN(x, 1.0f - eps);
        bleach[c] = 0.0f;
        if (!anyv(x > 0.0f)) continue;  // no bleaching above equilibrium: the usual case
        floatv ln_odds = logv(MAX(x, FLT_MIN)) - logv(1.0f - x);
        floatv I_x = expv((lsn_floor + ln_odds) / P->n);
        // 1 - (I / (I + I_x))^n without cancelling where I_x << I (reference.bleach_response)
        floatv ratio = MIN(I_x / MAX(In[c], FLT_MIN), 1e30f);
        floatv unmasked = one_minus_exp_negv(P->n * log1pv(ratio));
        bleach[c] = x > 0.0f ? (1.0f - R_now) * tonev(P, lsn, In[c] + I_x) * unmasked : 0.0f;
    }
    if (P->gain_along_adapting_light) {
        // u / max |u| in [-1, 1], then its unit vector; the side (cosine / AGREE_COS, clamped)
        floatv len_u = 0.0f, dot = 0.0f;
        u_max = MAX(u_max, FLT_MIN);
        for (int c = 0; c < 3; ++c) {
            u[c] = u[c] / u_max;
            len_u += u[c] * u[c];
        }
        len_u = MAX(sqrtv(len_u), FLT_MIN);
        for (int c = 0; c < 3; ++c) {
            u[c] = u[c] / len_u;
            dot -= ln_gain[c] * u[c];
        }
        len_g = sqrtv(len_g);
        floatv side = CLAMP(dot / MAX(len_g, FLT_MIN) / AGREE_COS, -1.0f, 1.0f);
        floatv scale = -len_g * side;
        for (int c = 0; c < 3; ++c) ln_gain[c] = scale * u[c];
    }
    for (int c = 0; c < 3; ++c)
        store_cellv(maps + c * plane + row, exp_shownv(ln_gain[c]), j, grid_w);
    rgbv_t add = matv_mul(P->H, bleach[0], bleach[1], bleach[2]);  // LMS bleaching -> RGB
    store_cellv(maps + 3 * plane + row, add.r, j, grid_w);
    store_cellv(maps + 4 * plane + row, add.g, j, grid_w);
    store_cellv(maps + 5 * plane + row, add.b, j, grid_w);
}

// The maps of the cells in [j0, j1] x [i0, i1], from the current state, in runs of VEC cells
// from the row's start; runs wholly inside the window [mj0, mj1] x [mi0, mi1] are left as they
// are (made already). Global size: the whole grid, (ceil(grid_w / VEC), grid_h), whatever the
// windows: PoCL compiles a kernel anew for each global size it meets (about 0.2 s).
__kernel void afterimage_maps(__constant const params_t *P, __global const float *down,
                              __global const float *surround, __global const float *state,
                              __global float *maps, __global const float *A, int low_w,
                              int low_h, int cell, int grid_w, int grid_h, float gx, float gy,
                              int j0, int i0, int j1, int i1, int mj0, int mi0, int mj1,
                              int mi1) {
    int j = get_global_id(0) * VEC, i = get_global_id(1);
    if (j >= grid_w || i < i0 || i > i1 || j + VEC <= j0 || j > j1) return;
    if (i >= mi0 && i <= mi1 && j >= mj0 && j + VEC - 1 <= mj1) return;
    int plane = grid_w * grid_h;
    size_t row = (size_t)i * grid_w;
    floatv st[9];
    for (int c = 0; c < 9; ++c) st[c] = load_cellv(state + c * plane + row, j, grid_w);
    mapsv(P, down, surround, st, maps, ln_sigma_n_of(P, A[0]), low_w, low_h, cell, grid_w, grid_h,
          gx, gy, j, i);
}

// The map blur of Sec. 2.4 (separable Gaussian, edges clamped, as blur_h then blur_v) in one
// pass, src -> dst, plane get_global_id(2) of the state's nine. Global size (ceil(grid_w / VEC),
// ceil(grid_h / rows), 9): a work-item makes `rows` rows of VEC cells. In one pass, not blur_h
// then blur_v: 0.46× as long for the usual 3 taps.

// (l's last lane, c's first VEC - 1) and (c's last VEC - 1, n's first): a run's neighbours.
#if VEC == 16
#define BEFORE_LANES 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30
#define AFTER_LANES 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16
#else
#define BEFORE_LANES 7, 8, 9, 10, 11, 12, 13, 14
#define AFTER_LANES 1, 2, 3, 4, 5, 6, 7, 8
#endif

// The 3 taps along row r at the VEC cells from j (a whole run), edges clamped: the neighbours
// are the run shifted by a lane, the cell before and after it shifted in (the edge cell itself
// at the row's ends), not two more loads of VEC cells, which straddle cache lines.
HOT floatv row_taps3v(__global const float *r, int j, int w, float t0, float t1, float t2) {
    floatv c = LOADV_G(r + j);
    floatv before = (floatv)(j > 0 ? r[j - 1] : c.s0);
    floatv after = (floatv)(j + VEC < w ? r[j + VEC] : LAST(c));
    return t0 * SHUFFLE2(before, c, BEFORE_LANES) + t1 * c +
           t2 * SHUFFLE2(c, after, AFTER_LANES);
}

__kernel void retina_blur(__global const float *src, __global float *dst,
                          __constant const float *taps, int radius, int grid_w, int grid_h,
                          int rows) {
    int j = get_global_id(0) * VEC, i0 = get_global_id(1) * rows, c = get_global_id(2);
    if (j >= grid_w || i0 >= grid_h) return;
    size_t plane = (size_t)c * grid_w * grid_h;
    __global const float *s = src + plane;  // this plane's first row
    __global float *d = dst + plane;
    int i1 = MIN(i0 + rows, grid_h);
    if (radius == 1 && j + VEC <= grid_w) {
        // The usual 3 taps: each row's horizontal pass made once and kept for the two rows
        // below (opencl.BLUR_ROWS: 0.85-0.89× as long as three passes per row in live steps).
        float t0 = taps[0], t1 = taps[1], t2 = taps[2];
        floatv above = row_taps3v(s + MAX(i0 - 1, 0) * grid_w, j, grid_w, t0, t1, t2);
        floatv here = row_taps3v(s + i0 * grid_w, j, grid_w, t0, t1, t2);
        for (int i = i0; i < i1; ++i) {
            floatv below = row_taps3v(s + MIN(i + 1, grid_h - 1) * grid_w, j, grid_w, t0, t1, t2);
            STOREV_G(d + (size_t)i * grid_w + j, t0 * above + t1 * here + t2 * below);
            above = here;
            here = below;
        }
        return;
    }
    int inner = j >= radius && j + VEC + radius <= grid_w;
    for (int i = i0; i < i1; ++i) {
        floatv acc = 0.0f;
        for (int dy = -radius; dy <= radius; ++dy) {
            __global const float *r = s + CLAMP(i + dy, 0, grid_h - 1) * grid_w;
            floatv h = 0.0f;
            if (inner) {
                for (int dx = -radius; dx <= radius; ++dx)
                    h += taps[dx + radius] * LOADV_G(r + j + dx);
            } else {
                for (int dx = -radius; dx <= radius; ++dx)
                    h += taps[dx + radius] * gatherv(r, CLAMP(j + dx + LANE_I, 0, grid_w - 1));
            }
            acc += taps[dy + radius] * h;
        }
        store_cellv(d + (size_t)i * grid_w, acc, j, grid_w);
    }
}

// Settling (layout.settle_plan): the state that steps of dt leave as it is, s = G(R s + (1 - R)
// s_inf), by Jacobi iterations. Calcium settles as 1 - c, the same equation (G keeps a
// constant), which in the dark is small and so exact in float32 where c, near 1, is not.
// retina_settle_init writes z = z_inf (B_inf; 1 - c_inf = R(I), Eq. 10; x_inf = I / sigma), R of
// the bleaching planes (calcium's and x's is decay_c everywhere), u = R z and b = (1 - R) z_inf, which the host blurs.
__kernel void retina_settle_init(__constant const params_t *P, __global const float *down,
                                 __global const float *surround, __global const float *A,
                                 int low_w, int low_h, int cell, int grid_w, int grid_h,
                                 float gx, float gy, float dt, float decay_c,
                                 __global float *state, __global float *rate, __global float *u,
                                 __global float *b) {
    int j = get_global_id(0) * VEC, i = get_global_id(1);
    if (j >= grid_w) return;
    size_t plane = (size_t)grid_w * grid_h, row = (size_t)i * grid_w;
    conev_t I = retina_inputv(down, surround, low_w, low_h, gx, gy, cell, grid_w, grid_h, j, i);
    floatv In[3] = {I.l, I.m, I.s};
    float lsn = ln_sigma_n_of(P, A[0]), xs = inv_sigma(P, lsn);
    for (int c = 0; c < 3; ++c) {
        floatv B_inf = bleach_infv(P, c, In[c]), y_inf = tonev(P, lsn, In[c]);
        floatv x_inf = In[c] * xs;
        floatv R = expv(-(P->b1[c] * In[c] + P->b2[c]) * dt);  // Eq. 5
        store_cellv(state + c * plane + row, B_inf, j, grid_w);
        store_cellv(state + (3 + c) * plane + row, y_inf, j, grid_w);
        store_cellv(rate + c * plane + row, R, j, grid_w);
        store_cellv(u + c * plane + row, R * B_inf, j, grid_w);
        store_cellv(u + (3 + c) * plane + row, decay_c * y_inf, j, grid_w);
        store_cellv(b + c * plane + row, (1.0f - R) * B_inf, j, grid_w);
        store_cellv(b + (3 + c) * plane + row, (1.0f - decay_c) * y_inf, j, grid_w);
        store_cellv(state + (6 + c) * plane + row, x_inf, j, grid_w);
        store_cellv(u + (6 + c) * plane + row, decay_c * x_inf, j, grid_w);
        store_cellv(b + (6 + c) * plane + row, (1.0f - decay_c) * x_inf, j, grid_w);
    }
}

// One Jacobi iteration, z <- (b + w - d R z) / (1 - d R) with w = G(u) and d = diag_x[j]
// diag_y[i], the diagonal of G (`diag` holds both); then u = R z for the next one, or, after
// the last, the state itself (c = 1 - z; B and x are z).
__kernel void retina_settle_step(__global float *state, __global float *u,
                                 __global const float *w, __global const float *b,
                                 __global const float *rate, float decay_c,
                                 __global const float *diag, int grid_w, int grid_h, int last) {
    int j = get_global_id(0) * VEC, i = get_global_id(1);
    if (j >= grid_w) return;
    size_t plane = (size_t)grid_w * grid_h, row = (size_t)i * grid_w;
    floatv d = load_cellv(diag, j, grid_w) * diag[grid_w + i];
    for (int c = 0; c < 9; ++c) {
        size_t at = c * plane + row;
        floatv R = c < 3 ? load_cellv(rate + at, j, grid_w) : (floatv)(decay_c);
        floatv dR = d * R;
        floatv z = load_cellv(b + at, j, grid_w) + load_cellv(w + at, j, grid_w);
        z = (z - dR * load_cellv(state + at, j, grid_w)) / (1.0f - dR);
        store_cellv(state + at, last && c >= 3 && c < 6 ? 1.0f - z : z, j, grid_w);
        store_cellv(u + at, R * z, j, grid_w);
    }
}
