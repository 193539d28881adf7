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
    int xe = MIN((x + 1) * cell, W), ye = MIN((y + 1) * cell, H);
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

// rho at every screen pixel (bilinear, edges clamped): it changes only with the scene, and the
// acuity and compose stages both read it. Global size (ceil(W / VEC), H).
__kernel void rho_upsample(__global const float *rho, __global float *rho_full, int low_w,
                           int low_h, int cell, int W, int H) {
    int x = get_global_id(0) * VEC, y = get_global_id(1);
    if (x >= W) return;
    lerpv_t tx = lerpv_at(low_w, ((float)x + 0.5f + LANE_F) / cell, 1);
    lerp1_t ty = lerp1_at(low_h, (y + 0.5f) / cell, 1);
    floatv r = bilinearv_get(rho, low_w, tx, ty, 0.0f);
    __global float *o = rho_full + (size_t)y * W + x;
    if (x + VEC <= W) STOREV_G(o, r);
    else storev_part(o, r, W - x);
}

// Eq. 15 with one noise field for all bands: d = number of finest bands dropped. The kept bands
// telescope (Eq. 14), so the result is Gaussian level d - 1 (level -1 is the scene itself).
// X is interpolated in space and time and renormalised so that it stays N(0, 1): `key` is the
// two key frames already mixed in time (and divided by their time norm) on the host, so here
// it is bilinear in space. Global size (ceil(W / VEC), H); with want_max, d_max gets the
// largest d (for the level-by-level bank).
__kernel void acuity_levels(__constant const params_t *P, __global const float *rho_full,
                            __global const float *key, float spacing, int nx, int W, int H,
                            __global uchar *d_map, volatile __global int *d_max,
                            int want_max) {
    int x = get_global_id(0) * VEC, y = get_global_id(1);
    if (x >= W) return;
    floatv r = loadv_row(rho_full + (size_t)y * W, x, W);
    floatv u = ((float)x + 0.5f + LANE_F) / spacing;
    float v = (y + 0.5f) / spacing;
    floatv fu = floorv(u);
    float fv = floor1(v);
    lerpv_t tx;
    tx.x0 = tx.a = TO_INTV(fu);
    tx.b = tx.a + 1;
    tx.wb = u - fu;
    tx.wa = 1.0f - tx.wb;
    int j0 = (int)fv;
    float fy = v - fv;
    __global const float *ra = key + j0 * nx, *rb = ra + nx;
    floatv s;
    floatv xm[XMIX_MAX];
    int K = xmixv(tx, xm);
    if (K > 0) {
        s = 0.0f;
        for (int k = 0; k < K; ++k) {
            int col = tx.x0.s0 + k;
            s += ((1 - fy) * ra[col] + fy * rb[col]) * xm[k];
        }
    } else {  // noise nodes closer than VEC / 6 pixels (tiny frames)
        s = (1 - fy) * (tx.wa * gatherv(ra, tx.a) + tx.wb * gatherv(ra, tx.b))
            + fy * (tx.wa * gatherv(rb, tx.a) + tx.wb * gatherv(rb, tx.b));
    }
    floatv norm = sqrtv((tx.wa * tx.wa + tx.wb * tx.wb) * ((1 - fy) * (1 - fy) + fy * fy));
    floatv q = r + P->g * s / norm;
    intv d = (intv)(0);
    for (int b = 0; b < P->bands; ++b) d -= (q <= P->rho_i[b]);  // a true comparison is -1
    __global uchar *o = d_map + (size_t)y * W + x;
    ucharv du = TO_UCHARV(d);
    if (x + VEC <= W) {
        STOREV_D(o, du);
    } else {
        uchar tmp[VEC];
        STOREV_PRIVATE(du, tmp);
        for (int i = 0; i < W - x; ++i) o[i] = tmp[i];
        d = (x + LANE_I >= W) ? 0 : d;
    }
    if (!want_max) return;
    int m = max_lane(d);
    if (m > *d_max) atomic_max(d_max, m);  // rarely contended: most reads see it done
}

// --- Eq. 14 on a scene that stays: a pick from levels made once ------------------------------
//
// Level l - 1 of each pixel that drops l bands, from `stack`: the scene (level -1) and its
// Gaussian levels 0 .. bands - 1, made once per scene by blur_h/blur_v, all in 16 bits
// (lum16_encode): level l - 1 at stack + l * stride, three planes each. A run of VEC pixels
// mostly drops the same number of bands (rho and the noise are smooth), so they read one level
// with vector loads; else the lanes that drop the most read theirs, and each level between (6 %
// of the runs of 8 on the lamp scene at 1280×720) is selected. The codes are copied, never
// decoded. Written without the bounds checks of loadv_row, the row's last pixels apart: with
// them the pick took 1.6× as long on PoCL.
__kernel void acuity_pick(__global const ushort *stack, int stride, __global const uchar *d_map,
                          __global ushort *G, int W, int H) {
    int x = get_global_id(0) * VEC, y = get_global_id(1);
    if (x >= W) return;
    size_t plane = (size_t)W * H, at = (size_t)y * W + x;
    if (x + VEC > W) {  // the row's last pixels, one at a time
        for (int i = 0; i < W - x; ++i) {
            __global const ushort *level = stack + (size_t)d_map[at + i] * stride;
            for (int c = 0; c < 3; ++c) G[c * plane + at + i] = level[c * plane + at + i];
        }
        return;
    }
    ucharv d = LOADV_D(d_map + at);
    int lo = min_lane(TO_INTV(d)), hi = max_lane(TO_INTV(d));
    ushortv dl = TO_USHORTV(d);  // a lane mask as wide as the codes
    for (int c = 0; c < 3; ++c) {
        size_t o = c * plane + at;  // this pixel's channel c, in every level and G
        ushortv g = LOADV_U16(stack + (size_t)lo * stride + o);
        if (hi > lo) {  // lanes that drop more than lo bands
            g = dl == (ushort)hi ? LOADV_U16(stack + (size_t)hi * stride + o) : g;
            for (int l = lo + 1; l < hi; ++l)
                g = dl == (ushort)l ? LOADV_U16(stack + (size_t)l * stride + o) : g;
        }
        STOREV_U16(G + o, g);
    }
}

// --- the acuity bank in tiles (CPU) ------------------------------------------------------------
//
// Eq. 14 needs Gaussian level d - 1 at each pixel, and level i is level i - 1 blurred by the
// increment i (the same separable taps, edges clamped, as the reference). Done level by level
// over the whole frame this streams the frame through memory twice per level. Here one
// work-item takes a TX×TY tile: it scans the tile's d once to see how many levels the tile
// needs, then per channel loads the scene around it with a halo of the summed radii into local
// memory, runs all those levels there (each level only where the following ones still need it)
// and writes G once. Bright tiles (d = 0) are a copy. Local size 1: the loops are written for
// one core.
//
// Buffer layout: buffer (bx, by) is screen (tx0 - PX + bx, ty0 - PY + by); PX is the halo
// rounded up to whole floatv plus one floatv of margin, so that rows are computed in floatv
// steps without reading outside the buffer. Columns and rows outside the screen hold copies of
// the edge (as the reference's clamped reads), refreshed after each pass.

inline void fill_cols(__local float *buf, int BW, int by0, int by1, int left, int right) {
    // Columns [0, left) copy column left; columns (right, BW) copy column right.
    for (int by = by0; by < by1; ++by) {
        __local float *row = buf + by * BW;
        if (left > 0 && left < BW) {
            float e = row[left];
            for (int bx = 0; bx < left; ++bx) row[bx] = e;
        }
        if (right >= 0 && right < BW - 1) {
            float e = row[right];
            for (int bx = right + 1; bx < BW; ++bx) row[bx] = e;
        }
    }
}

// Taps t[0 .. 2r] along s, s + d, ...: the general case of the unrolled CONV3/5/7 below.
inline floatv convv_l(__local const float *s, int d, __constant const float *t, int r) {
    floatv a = (floatv)(0.0f);
    for (int k = 0; k <= 2 * r; ++k) a += t[k] * LOADV_L(s + k * d);
    return a;
}

#define BANK_TX_MAX 128  // the widest tile (opencl.ACUITY_TILE)

__kernel void acuity_bank(__global const float *scene, __global const uchar *d_map,
                          __global ushort *G, __constant const float *taps,
                          __constant const int *levels, int W, int H, int TX, int TY,
                          __local float *lmem) {
    int tx0 = get_global_id(0) * TX, ty0 = get_global_id(1) * TY;
    if (tx0 >= W || ty0 >= H) return;
    int xe = MIN(tx0 + TX, W), ye = MIN(ty0 + TY, H), ow = xe - tx0;
    size_t plane = (size_t)W * H;

    // The tile's d: its maximum, and per level l the box of the pixels that drop more than l
    // bands (rows; columns in whole floatv chunks), so that each level is made only there and
    // around it (work in proportion to the pixels that need each level).
    int ylo[8], yhi[8], xlo[8], xhi[8];
    for (int l = 0; l < 8; ++l) ylo[l] = xlo[l] = 1 << 20, yhi[l] = xhi[l] = -1;
    ucharv cm[BANK_TX_MAX / VEC];  // per floatv chunk of columns, the largest d down the tile
    int chunks = (xe - tx0 + VEC - 1) / VEC;
    for (int k = 0; k < chunks; ++k) cm[k] = (ucharv)(0);
    int dmax = 0;
    for (int y = ty0; y < ye; ++y) {
        __global const uchar *drow = d_map + (size_t)y * W + tx0;
        ucharv rm = (ucharv)(0);
        for (int k = 0; k < chunks; ++k) {
            ucharv v;
            if (tx0 + VEC * (k + 1) <= xe) {
                v = LOADV_D(drow + VEC * k);
            } else {  // the screen's last columns
                uchar t[VEC] = {0};
                for (int i = 0; i < xe - tx0 - VEC * k; ++i) t[i] = drow[VEC * k + i];
                v = LOADV_PRIVATE(t);
            }
            cm[k] = MAX(cm[k], v);
            rm = MAX(rm, v);
        }
        int m = MIN(max_lane(TO_INTV(rm)), 8);
        for (int l = 0; l < m; ++l) ylo[l] = MIN(ylo[l], y - ty0), yhi[l] = y - ty0;
        dmax = MAX(dmax, m);
    }
    for (int k = 0; k < chunks; ++k) {
        int m = MIN(max_lane(TO_INTV(cm[k])), 8);
        for (int l = 0; l < m; ++l) xlo[l] = MIN(xlo[l], k), xhi[l] = k;
    }
    // The three channels in turn, on the one scan of d above (the boxes are the same).
    for (int c = 0; c < 3; ++c) {
        __global const float *src_g = scene + c * plane;
        __global ushort *dst_g = G + c * plane;
        if (dmax == 0) {  // nothing dropped: the scene itself
            for (int y = ty0; y < ye; ++y) {
                size_t k = (size_t)y * W;
                int x = tx0;
                for (; x + VEC <= xe; x += VEC)
                    STOREV_U16(dst_g + k + x, to_lum16v(LOADV_G(src_g + k + x)));
                for (; x < xe; ++x) dst_g[k + x] = to_lum16(src_g[k + x]);
            }
            continue;
        }
        // halo[l + 1] = rows/columns of level l (l = -1 is the scene) still needed around the tile.
        int halo[9];
        halo[dmax] = 0;
        for (int l = dmax - 1; l >= 0; --l) halo[l] = halo[l + 1] + levels[2 * l];
        int HX = halo[0];
        int PX = ((HX + VEC - 1) / VEC + 1) * VEC, PY = HX;
        int BW = TX + 2 * PX, BH = TY + 2 * PY;
        // One buffer holds the current level (the vertical pass overwrites the level it came from:
        // the horizontal pass has read it all by then), one the horizontal pass, one the output.
        __local float *buf_a = lmem, *tmp = lmem + BW * BH, *acc = lmem + 2 * BW * BH;

        // Where level l is needed, in buffer coordinates [nx0, nx1) x [ny0, ny1): the box of its
        // own pixels and the next level's region widened by that level's radius.
        int nx0[8], nx1[8], ny0[8], ny1[8];
        for (int l = dmax - 1; l >= 0; --l) {
            nx0[l] = PX + VEC * xlo[l], nx1[l] = PX + VEC * (xhi[l] + 1);
            ny0[l] = PY + ylo[l], ny1[l] = PY + yhi[l] + 1;
            if (l + 1 < dmax) {
                int r = levels[2 * (l + 1)];
                nx0[l] = MIN(nx0[l], nx0[l + 1] - r), nx1[l] = MAX(nx1[l], nx1[l + 1] + r);
                ny0[l] = MIN(ny0[l], ny0[l + 1] - r), ny1[l] = MAX(ny1[l], ny1[l + 1] + r);
            }
        }

        // Screen edges in buffer coordinates.
        int left = PX - tx0, right = PX + W - 1 - tx0, top = PY - ty0, bottom = PY + H - 1 - ty0;

        // The scene, edges clamped, where level 0 reads it.
        int r0 = levels[0];
        int ly0 = MAX(ny0[0] - r0, 0), ly1 = MIN(ny1[0] + r0, BH);
        int lx0 = MAX((nx0[0] - r0) / VEC * VEC, 0);
        int lx1 = MIN((nx1[0] + r0 + VEC - 1) / VEC * VEC, BW);
        for (int by = ly0; by < ly1; ++by) {
            int y = CLAMP(ty0 - PY + by, 0, H - 1);
            __global const float *row = src_g + (size_t)y * W;
            __local float *brow = buf_a + by * BW;
            for (int bx = lx0; bx < lx1; bx += VEC) {
                int x = tx0 - PX + bx;
                floatv val;
                if (x >= 0 && x + VEC <= W) val = LOADV_G(row + x);
                else val = gatherv(row, CLAMP(x + LANE_I, 0, W - 1));
                STOREV_L(brow + bx, val);
            }
        }
        // The output starts as the scene (d = 0).
        for (int y = 0; y < ye - ty0; ++y) {
            __global const float *grow = src_g + (size_t)(ty0 + y) * W + tx0;
            __local float *arow = acc + y * TX;
            int x = 0;
            for (; x + VEC <= ow; x += VEC) STOREV_L(arow + x, LOADV_G(grow + x));
            for (; x < ow; ++x) arow[x] = grow[x];
        }

        __local float *src = buf_a, *dst = buf_a;
        for (int l = 0; l < dmax; ++l) {
            int r = levels[2 * l];
            __constant const float *t = taps + levels[2 * l + 1];
            int cx0 = nx0[l] / VEC * VEC, cx1 = (nx1[l] + VEC - 1) / VEC * VEC;  // floatv steps
            // Horizontal pass on the rows the vertical pass reads, inside the screen.
            int vy0 = MAX(ny0[l], top), vy1 = MIN(ny1[l], bottom + 1);
            int ry0 = MAX(vy0 - r, top), ry1 = MIN(vy1 + r, bottom + 1);
            float t0 = t[0], t1 = t[MIN(1, 2 * r)], t2 = t[MIN(2, 2 * r)], t3 = t[MIN(3, 2 * r)];
            float t4 = t[MIN(4, 2 * r)], t5 = t[MIN(5, 2 * r)], t6 = t[MIN(6, 2 * r)];
    #define H_PASS(CONV)                                                      \
        for (int by = ry0; by < ry1; ++by) {                                  \
            __local const float *s = src + by * BW - r;                       \
            __local float *o = tmp + by * BW;                                 \
            for (int bx = cx0; bx < cx1; bx += VEC) STOREV_L(o + bx, CONV(s + bx, 1)); \
        }
    #define V_PASS(CONV)                                                      \
        for (int by = vy0; by < vy1; ++by) {                                  \
            __local const float *s = tmp + (by - r) * BW;                     \
            __local float *o = dst + by * BW;                                 \
            for (int bx = cx0; bx < cx1; bx += VEC) STOREV_L(o + bx, CONV(s + bx, BW)); \
        }
    #define CONV3(s, d) (t0 * LOADV_L(s) + t1 * LOADV_L((s) + (d)) + t2 * LOADV_L((s) + 2 * (d)))
    #define CONV5(s, d) (CONV3(s, d) + t3 * LOADV_L((s) + 3 * (d)) + t4 * LOADV_L((s) + 4 * (d)))
    #define CONV7(s, d) (CONV5(s, d) + t5 * LOADV_L((s) + 5 * (d)) + t6 * LOADV_L((s) + 6 * (d)))
    #define CONVN(s, d) convv_l(s, d, t, r)
            if (r == 1) {
                H_PASS(CONV3)
            } else if (r == 2) {
                H_PASS(CONV5)
            } else if (r == 3) {
                H_PASS(CONV7)
            } else {
                H_PASS(CONVN)
            }
            // Rows above and below the screen repeat its edge rows.
            for (int by = vy0 - r; by < ry0; ++by)
                for (int bx = cx0; bx < cx1; bx += VEC)
                    STOREV_L(tmp + by * BW + bx, LOADV_L(tmp + top * BW + bx));
            for (int by = ry1; by < vy1 + r; ++by)
                for (int bx = cx0; bx < cx1; bx += VEC)
                    STOREV_L(tmp + by * BW + bx, LOADV_L(tmp + bottom * BW + bx));
            // Vertical pass where this level is still needed, inside the screen.
            if (r == 1) {
                V_PASS(CONV3)
            } else if (r == 2) {
                V_PASS(CONV5)
            } else if (r == 3) {
                V_PASS(CONV7)
            } else {
                V_PASS(CONVN)
            }
            fill_cols(dst, BW, vy0, vy1, left, right);
            // Pixels that drop l + 1 bands show this level.
            uchar want = (uchar)(l + 1);
            for (int y = ylo[l]; y <= yhi[l]; ++y) {
                __global const uchar *drow = d_map + (size_t)(ty0 + y) * W + tx0;
                __local float *arow = acc + y * TX;
                __local const float *lrow = dst + (PY + y) * BW + PX;
                int x = 0;
                for (; x + VEC <= ow; x += VEC) {
                    intv hit = TO_INTV(LOADV_D(drow + x) == (ucharv)(want));
                    STOREV_L(arow + x, hit ? LOADV_L(lrow + x) : LOADV_L(arow + x));
                }
                for (; x < ow; ++x)
                    if (drow[x] == want) arow[x] = lrow[x];
            }
        }
        for (int y = 0; y < ye - ty0; ++y) {
            __global ushort *grow = dst_g + (size_t)(ty0 + y) * W + tx0;
            __local const float *arow = acc + y * TX;
            int x = 0;
            for (; x + VEC <= ow; x += VEC) STOREV_U16(grow + x, to_lum16v(LOADV_L(arow + x)));
            for (; x < ow; ++x) grow[x] = to_lum16(arow[x]);
        }
    }
}
