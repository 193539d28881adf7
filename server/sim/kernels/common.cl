// Shared by every stage: helpers, sampling and the separable Gaussian blur (params_t: see below).
// Maps are planar (channel, row, column); pixel i has its centre at coordinate i + 0.5.
//
// Speed on the CPU (PoCL). Two things matter:
// - PoCL vectorises across work-items only for simple straight-line kernels, and none of the
//   model's per-pixel kernels qualifies (calls, branches, float3). So the per-pixel kernels
//   make 8 neighbouring pixels of a row per work-item as float8 (one AVX register). On a GPU the
//   same code runs with 8 pixels per thread, which costs little.
// - PoCL's builtin library (vload8, min, clamp, select, floor, convert_*, exp, ...) is compiled
//   for a generic CPU (target "haswell" in the PyPI build), and LLVM will not inline it into
//   kernels compiled for the host CPU (e.g. znver3: "conflicting attributes"). Every builtin is
//   then a function call, which also spills all vector registers. So the hot code uses
//   operators, the macros below (clang builtins under PoCL, GAZEHDR_POCL) and its own exp8 and
//   log8, all of which compile to plain instructions. Build with POCL_LEAVE_KERNEL_COMPILER_
//   TEMP_FILES=1 and `objdump -d` the kernel .so in the PoCL cache to check: no `call`s.

#ifdef GAZEHDR_POCL  // operators and clang builtins, which compile to single instructions
typedef float8 float8_u __attribute__((aligned(4)));  // float8 at any float address
typedef uchar8 uchar8_u __attribute__((aligned(1)));
#define LOAD8_G(p) (*(__global const float8_u *)(p))
#define LOAD8_L(p) (*(__local const float8_u *)(p))
#define STORE8_G(p, v) (*(__global float8_u *)(p) = (v))
#define STORE8_L(p, v) (*(__local float8_u *)(p) = (v))
#define LOAD8_D(p) (*(__global const uchar8_u *)(p))
#define STORE8_D(p, v) (*(__global uchar8_u *)(p) = (v))
#define TO_INT8(x) __builtin_convertvector(x, int8)  // toward zero, as convert_int8
#define TO_FLOAT8(x) __builtin_convertvector(x, float8)
#define TO_UCHAR8(x) __builtin_convertvector(x, uchar8)
#define AS_INT8(x) __builtin_astype(x, int8)
#define AS_FLOAT8(x) __builtin_astype(x, float8)
typedef float4 float4_u __attribute__((aligned(4)));
#define LOAD4_G(p) (*(__global const float4_u *)(p))
typedef uint8 uint8_u __attribute__((aligned(4)));
#define STORE8_UI(p, v) (*(__global uint8_u *)(p) = (v))
#if defined(__AVX__)  // sqrt() on a float8 is a library call too
#define SQRT8(x) __builtin_astype(__builtin_ia32_sqrtps256(__builtin_astype(x, __v8sf_t)), float8)
typedef float __v8sf_t __attribute__((__vector_size__(32)));
#else
#define SQRT8(x) sqrt(x)
#endif
#else  // other implementations inline their builtins
#define LOAD8_G(p) vload8(0, p)
#define LOAD8_L(p) vload8(0, p)
#define LOAD4_G(p) vload4(0, p)
#define STORE8_G(p, v) vstore8(v, 0, p)
#define STORE8_L(p, v) vstore8(v, 0, p)
#define LOAD8_D(p) vload8(0, p)
#define STORE8_D(p, v) vstore8(v, 0, p)
#define TO_INT8(x) convert_int8(x)
#define TO_FLOAT8(x) convert_float8(x)
#define TO_UCHAR8(x) convert_uchar8(x)
#define AS_INT8(x) as_int8(x)
#define AS_FLOAT8(x) as_float8(x)
#define STORE8_UI(p, v) vstore8(v, 0, p)
#define SQRT8(x) sqrt(x)
#endif
#define MIN(a, b) ((a) < (b) ? (a) : (b))
#define MAX(a, b) ((a) > (b) ? (a) : (b))
#define CLAMP(x, lo, hi) MIN(MAX(x, lo), hi)
#define ABS8(x) MAX(x, -(x))  // fabs() is a library call under PoCL

// Helpers are always inlined: PoCL's compiler otherwise keeps the larger ones (compose8,
// retina_input8, maps8) as calls, and a call passes its float8 arguments and results through
// the stack and spills every vector register around it.
#define HOT inline __attribute__((always_inline))

// Whether any lane of a comparison is true (any() is a library call under PoCL, see above).
HOT int any8(int8 m) {
    int4 a = m.lo | m.hi;
    int2 b = a.lo | a.hi;
    return (b.x | b.y) != 0;
}

// One vroundps where there is AVX (compose 0.95-0.98×): floor() is a library call under PoCL.
HOT float8 floor8(float8 x) {
#if defined(GAZEHDR_POCL) && defined(__AVX__)
    return __builtin_astype(__builtin_ia32_roundps256(__builtin_astype(x, __v8sf_t), 9), float8);
#else
    float8 t = TO_FLOAT8(TO_INT8(x));
    return t + TO_FLOAT8(t > x);  // a true comparison is -1
#endif
}

HOT float floor1(float x) {
    float t = (float)(int)x;
    return t > x ? t - 1.0f : t;
}

// params_t, the parameter block every kernel takes as P, is not declared here: build_program
// puts it in front of the program, generated from Params by gazehdr/sim/kernel_params.py (its
// fields are Params' under the same names, plus a few derived ones; print it with
// `python -m gazehdr.sim.kernel_params`).

#define LN10 2.302585093f
#define LN2 0.693147181f
#define LOG2E 1.442695041f  // 1 / ln 2
#define VEC 8  // pixels per work-item in the vectorised kernels
#define LANE_I ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#define LANE_F ((float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f))

HOT float8 gather8(__global const float *p, int8 i) {
    return (float8)(p[i.s0], p[i.s1], p[i.s2], p[i.s3], p[i.s4], p[i.s5], p[i.s6], p[i.s7]);
}

// Pixels x .. x+7 of a row of n; lanes past the end repeat the last pixel (never read beyond).
HOT float8 load8_row(__global const float *row, int x, int n) {
    if (x + VEC <= n) return LOAD8_G(row + x);
    return gather8(row, MIN(x + LANE_I, n - 1));
}

// Stores lanes 0 .. n-1 of v (n <= 8; n < 8 at the end of a row).
HOT void store8_part(__global float *p, float8 v, int n) {
    if (n > 0) p[0] = v.s0;
    if (n > 1) p[1] = v.s1;
    if (n > 2) p[2] = v.s2;
    if (n > 3) p[3] = v.s3;
    if (n > 4) p[4] = v.s4;
    if (n > 5) p[5] = v.s5;
    if (n > 6) p[6] = v.s6;
    if (n > 7) p[7] = v.s7;
}

HOT float3 mat3_mul(__constant const float *m, float3 v) {
    return (float3)(m[0] * v.x + m[1] * v.y + m[2] * v.z,
                    m[3] * v.x + m[4] * v.y + m[5] * v.z,
                    m[6] * v.x + m[7] * v.y + m[8] * v.z);
}

HOT float dot3(__constant const float *w, float3 v) {
    return w[0] * v.x + w[1] * v.y + w[2] * v.z;
}

HOT float3 load3(__global const float *img, int plane, int i) {
    return (float3)(img[i], img[plane + i], img[2 * plane + i]);
}

// One axis of a bilinear lookup: the two taps (clamped indices) and their weights, which in
// border mode are 0 for taps outside [0, n) so that the missing weight can go to a border value.
typedef struct {
    int8 x0;  // first tap, unclamped
    int8 a, b;
    float8 wa, wb;
} lerp8_t;

typedef struct {
    int a, b;
    float wa, wb;
} lerp1_t;

HOT lerp8_t lerp8_at(int n, float8 x, int clamp_edges) {
    float8 u = x - 0.5f;
    float8 fu = floor8(u);
    int8 x0 = TO_INT8(fu);
    float8 f = u - fu;
    lerp8_t t;
    t.x0 = x0;
    t.a = CLAMP(x0, 0, n - 1);
    t.b = CLAMP(x0 + 1, 0, n - 1);
    t.wa = 1.0f - f;
    t.wb = f;
    if (!clamp_edges) {
        t.wa = (x0 >= 0 && x0 < n) ? t.wa : 0.0f;
        t.wb = (x0 >= -1 && x0 < n - 1) ? t.wb : 0.0f;
    }
    return t;
}

HOT lerp1_t lerp1_at(int n, float x, int clamp_edges) {
    float u = x - 0.5f;
    float fu = floor1(u);
    int x0 = (int)fu;
    float f = u - fu;
    lerp1_t t;
    t.a = CLAMP(x0, 0, n - 1);
    t.b = CLAMP(x0 + 1, 0, n - 1);
    t.wa = 1.0f - f;
    t.wb = f;
    if (!clamp_edges) {
        t.wa = (x0 >= 0 && x0 < n) ? t.wa : 0.0f;
        t.wb = (x0 >= -1 && x0 < n - 1) ? t.wb : 0.0f;
    }
    return t;
}

// Bilinear value of a w-wide map at 8 x positions on one row position; `border` takes the
// weight of taps outside the map (border mode).
HOT float8 bilinear8_get(__global const float *img, int w, lerp8_t tx, lerp1_t ty,
                            float border) {
    __global const float *ra = img + ty.a * w, *rb = img + ty.b * w;
    float8 top = tx.wa * gather8(ra, tx.a) + tx.wb * gather8(ra, tx.b);
    float8 bot = tx.wa * gather8(rb, tx.a) + tx.wb * gather8(rb, tx.b);
    float8 w_in = (ty.wa + ty.wb) * (tx.wa + tx.wb);
    return ty.wa * top + ty.wb * bot + (1.0f - w_in) * border;
}

// The x part of a lookup as weights per source column: lane i takes wa at column x0_i and wb
// at x0_i + 1, and m[k] is the weight of column x0_0 + k (k < K). When the 8 positions are
// less than a column apart (cell >= 2), K <= 6 columns serve them all, and a lookup costs K
// broadcast loads and FMAs per row instead of 16 gathered loads. Returns K, 0 if K > 8.
HOT int xmix8(lerp8_t t, float8 *m) {
    int K = t.x0.s7 - t.x0.s0 + 2;
    if (K > 8) return 0;
    int8 o = t.x0 - t.x0.s0;
    for (int k = 0; k < K; ++k) m[k] = (o == k ? t.wa : 0.0f) + (o == k - 1 ? t.wb : 0.0f);
    return K;
}

// The cone input (L, M, S) at retina cell (j, i): the low-res scene `down` at gaze + retinal
// offset, bilinear; a tap off the screen reads the `surround` map at the nearest screen cell
// (reference.retina_input; 8 cells at once: retina_input8 in sec2_2_afterimages.cl).
HOT float3 retina_lms1(__global const float *down, __global const float *surround, int low_w,
                          int low_h, float gx, float gy, int cell, int grid_w, int grid_h, int j,
                          int i) {
    float u = gx / cell + (j - 0.5f * grid_w), v = gy / cell + (i - 0.5f * grid_h);
    float fu = floor1(u), fv = floor1(v);
    int x0 = (int)fu, y0 = (int)fv, plane = low_w * low_h;
    float3 acc = (float3)(0.0f);
    for (int dy = 0; dy < 2; ++dy) {
        for (int dx = 0; dx < 2; ++dx) {
            int x = x0 + dx, y = y0 + dy;
            int k = CLAMP(y, 0, low_h - 1) * low_w + CLAMP(x, 0, low_w - 1);
            int on = x >= 0 && x < low_w && y >= 0 && y < low_h;
            float3 val = on ? load3(down, plane, k) : load3(surround, plane, k);
            acc += (dx ? u - fu : 1.0f - (u - fu)) * (dy ? v - fv : 1.0f - (v - fv)) * val;
        }
    }
    return acc;
}

// The taps x0 + lane of a row of n, 0 outside it (8 consecutive taps, border value 0).
HOT float8 row_taps8(__global const float *row, int x0, int n) {
    if (x0 >= 0 && x0 + VEC <= n) return LOAD8_G(row + x0);
    int8 x = x0 + LANE_I;
    float8 v = gather8(row, CLAMP(x, 0, n - 1));
    return (x >= 0 && x < n) ? v : 0.0f;
}

// exp and log of float8, inline (the library's are calls, see the top), within a few ulp.
// exp8 is Cephes' expf (S. L. Moshier) and takes x in [-87, 88] (clamped: e^-87 = 1.6e-38
// stands for 0); log8 takes x > 0 (normal numbers).
HOT float8 exp8(float8 x) {
    x = CLAMP(x, -87.0f, 88.0f);
    float8 n = floor8(x * 1.44269504088896341f + 0.5f);
    x = x - n * 0.693359375f + n * 2.12194440e-4f;
    float8 z = x * x;
    float8 y = 1.9875691500e-4f;
    y = y * x + 1.3981999507e-3f;
    y = y * x + 8.3334519073e-3f;
    y = y * x + 4.1665795894e-2f;
    y = y * x + 1.6666665459e-1f;
    y = y * x + 5.0000001201e-1f;
    y = y * z + x + 1.0f;
    return y * AS_FLOAT8((TO_INT8(n) + 127) << 23);
}

// x = m 2^e with m in [sqrt(1/2), sqrt(2)): sets *e and returns atanh(t) = (ln m) / 2,
// t = (m - 1) / (m + 1), |t| < 0.172: the series to t^7 is within 1e-7 relative.
HOT float8 half_log_mantissa8(float8 x, int8 *e) {
    int8 bits = AS_INT8(x);
    *e = ((bits - 0x3f3504f3) >> 23);  // exponent after moving m into [sqrt(1/2), sqrt(2))
    float8 m = AS_FLOAT8(bits - (*e << 23));
    float8 t = (m - 1.0f) / (m + 1.0f);
    float8 u = t * t;
    float8 p = u * (1.0f / 7.0f) + 1.0f / 5.0f;
    p = p * u + 1.0f / 3.0f;
    return p * u * t + t;
}

HOT float8 log8(float8 x) {
    int8 e;
    float8 p = half_log_mantissa8(x, &e);
    float8 fe = TO_FLOAT8(e);
    return (p + p) + fe * 0.693359375f - fe * 2.12194440e-4f;
}

// ln(1 + x) for x >= 0, exact where x is tiny (log8(1 + x) would lose x to rounding): the
// series to x^4 below 0.01 (within 2e-9 relative there).
HOT float8 log1p8(float8 x) {
    float8 series = x * (1.0f - x * (0.5f - x * (1.0f / 3.0f - x * 0.25f)));
    return x < 0.01f ? series : log8(1.0f + x);
}

// 1 - e^-y for y >= 0, likewise: the series to y^4 below 0.01.
HOT float8 one_minus_exp_neg8(float8 y) {
    float8 series = y * (1.0f - y * (0.5f - y * (1.0f / 6.0f - y * (1.0f / 24.0f))));
    return y < 0.01f ? series : 1.0f - exp8(-y);
}

// x^y for x >= 0.
HOT float8 pow8_pos(float8 x, float y) {
    return x > 0.0f ? exp8(y * log8(MAX(x, FLT_MIN))) : 0.0f;
}

// log2 and 2^x of float8 to display precision, for what is only shown (compose), at about half
// the cost of log8 and exp8: log2 of the mantissa m in [sqrt(1/2), sqrt(2)) by a degree-5
// polynomial in m - 1 (no division), within 3.5e-5; 2^f on [-0.5, 0.5] by a degree-4 one with
// 2^0 = 1 exactly, within 3.5e-6 relative (both fitted on Chebyshev nodes; measured in float32
// by tests/test_kernel_math.py). log2_shown8 takes x > 0 (normal numbers); exp2_shown8 takes z
// in [-126, 126].
HOT float8 log2_shown8(float8 x) {
    int8 bits = AS_INT8(x);
    int8 e = (bits - 0x3f3504f3) >> 23;  // exponent after moving m into [sqrt(1/2), sqrt(2))
    float8 t = AS_FLOAT8(bits - (e << 23)) - 1.0f;
    float8 p = 2.493932843e-01f;
    p = p * t - 3.894295692e-01f;
    p = p * t + 4.858239293e-01f;
    p = p * t - 7.206443548e-01f;
    p = p * t + 1.442639351e+00f;
    return p * t + TO_FLOAT8(e);
}

HOT float8 exp2_shown8(float8 z) {
    float8 n = floor8(z + 0.5f);
    float8 f = z - n;
    float8 q = 9.600402787e-03f;
    q = q * f + 5.591693521e-02f;
    q = q * f + 2.402371913e-01f;
    q = q * f + 6.931219697e-01f;
    q = q * f + 1.0f;
    return q * AS_FLOAT8((TO_INT8(n) + 127) << 23);
}

// ln and e^x from the same, for what is only shown (the afterimage maps): ln within 2.5e-5, e^x
// within 1e-5 relative for x in [-87, 87] and clamped there beyond.
HOT float8 log_shown8(float8 x) { return log2_shown8(x) * LN2; }
HOT float8 exp_shown8(float8 x) { return exp2_shown8(CLAMP(x, -87.0f, 87.0f) * LOG2E); }

// x^y for x in [0, 1] and y > 0, the display gamma: within 1.4e-5 relative (1e-5 absolute) of
// x^0.455 over all floats in (0, 1], a tenth of a 10-bit step; 0^y = 0 and 1^y = 1 exactly.
HOT float8 pow8_unit(float8 x, float y) {
    float8 r = exp2_shown8(MAX(y * log2_shown8(MAX(x, FLT_MIN)), -126.0f));
    return x > 0.0f ? r : 0.0f;
}

// Naka-Rushton response (Eq. 1-2) with sigma^n = I_bar^(n-m) K^m, in logs: finite everywhere;
// no light gives exactly 0 so that black stays black.
HOT float8 tone8(__constant const params_t *P, float ln_sigma_n, float8 I) {
    float8 e = exp8(MIN(ln_sigma_n - P->n * log8(MAX(I, FLT_MIN)), 80.0f));
    return I > 0.0f ? 1.0f / (1.0f + e) : 0.0f;
}

// tone8 to display precision (compose): within 2e-5 relative of it.
HOT float8 tone8_shown(__constant const params_t *P, float ln_sigma_n, float8 I) {
    float8 z = ln_sigma_n * LOG2E - P->n * log2_shown8(MAX(I, FLT_MIN));
    float8 e = exp2_shown8(CLAMP(z, -125.0f, 115.0f));  // e^-87 .. e^80, as tone8's clamps
    return I > 0.0f ? 1.0f / (1.0f + e) : 0.0f;
}

HOT float ln_sigma_n_of(__constant const params_t *P, float A) {
    return P->n_minus_m * A * LN10 + P->ln_K_m;
}

// Separable Gaussian with edge clamping. Each work-item filters 8 neighbouring pixels of a
// row as one float8. Global size (ceil(w / 8), h, channels).
__kernel void blur_h(__global const float *src, __global float *dst, __constant float *taps,
                     int radius, int w, int h) {
    int x = get_global_id(0) * VEC, y = get_global_id(1), c = get_global_id(2);
    if (x >= w) return;
    size_t row0 = ((size_t)c * h + y) * w;
    __global const float *row = src + row0;
    if (x >= radius && x + VEC + radius <= w) {
        float8 acc = (float8)(0.0f);
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * LOAD8_G(row + x + k);
        STORE8_G(dst + row0 + x, acc);
        return;
    }
    for (int i = x; i < MIN(x + VEC, w); ++i) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * row[CLAMP(i + k, 0, w - 1)];
        dst[row0 + i] = acc;
    }
}

// Vertical pass. With level >= 0 it also serves the level-by-level acuity bank (Eq. 14):
// pixels whose number of dropped bands d equals level + 1 copy this level into G.
__kernel void blur_v(__global const float *src, __global float *dst, __constant float *taps,
                     int radius, int w, int h, __global const uchar *d_map, __global float *G,
                     int level) {
    int x = get_global_id(0) * VEC, y = get_global_id(1), c = get_global_id(2);
    if (x >= w) return;
    __global const float *plane = src + (size_t)c * h * w;
    size_t out0 = ((size_t)c * h + y) * w;
    if (x + VEC <= w) {
        float8 acc = (float8)(0.0f);
        for (int k = -radius; k <= radius; ++k)
            acc += taps[k + radius] * LOAD8_G(plane + CLAMP(y + k, 0, h - 1) * w + x);
        STORE8_G(dst + out0 + x, acc);
        if (level >= 0) {
            int8 hit = TO_INT8(LOAD8_D(d_map + y * w + x) == (uchar8)(level + 1));
            STORE8_G(G + out0 + x, hit ? acc : LOAD8_G(G + out0 + x));
        }
        return;
    }
    for (int i = x; i < w; ++i) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * plane[CLAMP(y + k, 0, h - 1) * w + i];
        dst[out0 + i] = acc;
        if (level >= 0 && d_map[y * w + i] == level + 1) G[out0 + i] = acc;
    }
}

// --- colour on 8 pixels ------------------------------------------------------------------

typedef struct {
    float8 r, g, b;
} rgb8_t;

HOT float8 dot8(__constant const float *w, float8 r, float8 g, float8 b) {
    return w[0] * r + w[1] * g + w[2] * b;
}

HOT rgb8_t mat8_mul(__constant const float *m, float8 r, float8 g, float8 b) {
    rgb8_t o;
    o.r = m[0] * r + m[1] * g + m[2] * b;
    o.g = m[3] * r + m[4] * g + m[5] * b;
    o.b = m[6] * r + m[7] * g + m[8] * b;
    return o;
}
