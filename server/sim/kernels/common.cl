// Shared by every stage: helpers, sampling and the separable Gaussian blur (params_t: see below).
// Past 600 lines because it is the one prelude every program is built on (cl_program.py puts it
// first): the vector macros, the lane helpers, sampling, the blur, G's 16 bits and the
// display-precision math. Split, every program and gazehdr.yuv would list its parts in order.
// Maps are planar (channel, row, column); pixel i has its centre at coordinate i + 0.5.
//
// Speed on the CPU (PoCL). Two things matter:
// - PoCL vectorises across work-items only for simple straight-line kernels, and none of the
//   model's per-pixel kernels qualifies (calls, branches, float3). So the per-pixel kernels
//   make VEC neighbouring pixels of a row per work-item as one floatv: VEC is 16 (float16, one
//   AVX-512 register) where PoCL builds for AVX-512, else 8 (float8, one AVX register); the
//   host passes it as -DVEC (cl_program.vector_width). On a GPU the same code runs with 8 pixels
//   per thread, which costs little.
// - PoCL's builtin library (vload8, min, clamp, select, floor, convert_*, exp, ...) is compiled
//   for a generic CPU (target "haswell" in the PyPI build), and LLVM will not inline it into
//   kernels compiled for the host CPU (e.g. znver3: "conflicting attributes"). Every builtin is
//   then a function call, which also spills all vector registers. So the hot code uses
//   operators, the macros below (clang builtins under PoCL, GAZEHDR_POCL) and its own expv and
//   logv, all of which compile to plain instructions. Build with POCL_LEAVE_KERNEL_COMPILER_
//   TEMP_FILES=1 and `objdump -d` the kernel .so in the PoCL cache to check: no `call`s.
//
// Names: a `v` where the float8 code had an 8 (floatv, expv, LOADV_G) is VEC lanes wide; an 8
// is 8 lanes whatever VEC is (the halves a float16 is handled in where lanes are listed).

#ifndef VEC
#define VEC 8
#endif
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)  // CAT(float, VEC): float8 or float16
typedef CAT(float, VEC) floatv;
typedef CAT(int, VEC) intv;
typedef CAT(uint, VEC) uintv;
typedef CAT(uchar, VEC) ucharv;
typedef CAT(ushort, VEC) ushortv;
#if VEC == 16
#define LANE_I ((intv)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define LAST(v) ((v).sf)
#elif VEC == 8
#define LANE_I ((intv)(0, 1, 2, 3, 4, 5, 6, 7))
#define LAST(v) ((v).s7)
#else
#error "VEC is 8 or 16"
#endif

#ifdef GAZEHDR_POCL  // operators and clang builtins, which compile to single instructions
typedef float8 float8_u __attribute__((aligned(4)));  // float8 at any float address
typedef floatv floatv_u __attribute__((aligned(4)));
typedef ucharv ucharv_u __attribute__((aligned(1)));
typedef uintv uintv_u __attribute__((aligned(4)));
typedef ushortv ushortv_u __attribute__((aligned(2)));
typedef float4 float4_u __attribute__((aligned(4)));
#define LOAD4_G(p) (*(__global const float4_u *)(p))
#define LOAD8_G(p) (*(__global const float8_u *)(p))
#define STORE8_G(p, v) (*(__global float8_u *)(p) = (v))
#define TO_INT8(x) __builtin_convertvector(x, int8)
#define TO_FLOAT8(x) __builtin_convertvector(x, float8)
#define LOADV_G(p) (*(__global const floatv_u *)(p))
#define LOADV_L(p) (*(__local const floatv_u *)(p))
#define STOREV_G(p, v) (*(__global floatv_u *)(p) = (v))
#define STOREV_L(p, v) (*(__local floatv_u *)(p) = (v))
#define LOADV_D(p) (*(__global const ucharv_u *)(p))
#define STOREV_D(p, v) (*(__global ucharv_u *)(p) = (v))
#define STOREV_UI(p, v) (*(__global uintv_u *)(p) = (v))
#define LOADV_UI(p) (*(__global const uintv_u *)(p))
// Lanes of a and b joined, picked by constant indices (shuffle2() is a library call under PoCL).
#define SHUFFLE2(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)
#define LOADV_U16(p) (*(__global const ushortv_u *)(p))
#define STOREV_U16(p, v) (*(__global ushortv_u *)(p) = (v))
#define TO_USHORTV(x) __builtin_convertvector(x, ushortv)
#define TO_INTV(x) __builtin_convertvector(x, intv)  // toward zero, as convert_int8
#define TO_FLOATV(x) __builtin_convertvector(x, floatv)
#define TO_UCHARV(x) __builtin_convertvector(x, ucharv)
#define AS_INTV(x) __builtin_astype(x, intv)
#define AS_FLOATV(x) __builtin_astype(x, floatv)
#else  // other implementations inline their builtins
#define LOAD4_G(p) vload4(0, p)
#define LOAD8_G(p) vload8(0, p)
#define STORE8_G(p, v) vstore8(v, 0, p)
#define TO_INT8(x) convert_int8(x)
#define TO_FLOAT8(x) convert_float8(x)
#define LOADV_G(p) CAT(vload, VEC)(0, p)
#define LOADV_L(p) CAT(vload, VEC)(0, p)
#define STOREV_G(p, v) CAT(vstore, VEC)(v, 0, p)
#define STOREV_L(p, v) CAT(vstore, VEC)(v, 0, p)
#define LOADV_D(p) CAT(vload, VEC)(0, p)
#define STOREV_D(p, v) CAT(vstore, VEC)(v, 0, p)
#define STOREV_UI(p, v) CAT(vstore, VEC)(v, 0, p)
#define LOADV_UI(p) CAT(vload, VEC)(0, p)
#define SHUFFLE2(a, b, ...) shuffle2(a, b, (uintv)(__VA_ARGS__))
#define LOADV_U16(p) CAT(vload, VEC)(0, p)
#define STOREV_U16(p, v) CAT(vstore, VEC)(v, 0, p)
#define TO_USHORTV(x) CAT(convert_ushort, VEC)(x)
#define TO_INTV(x) CAT(convert_int, VEC)(x)
#define TO_FLOATV(x) CAT(convert_float, VEC)(x)
#define TO_UCHARV(x) CAT(convert_uchar, VEC)(x)
#define AS_INTV(x) CAT(as_int, VEC)(x)
#define AS_FLOATV(x) CAT(as_float, VEC)(x)
#endif
// Where PoCL builds for AVX or AVX-512, floor and sqrt as single instructions (vroundps,
// vrndscaleps, vsqrtps): floor() and sqrt() are library calls under PoCL (compose 0.95-0.98×).
#if defined(GAZEHDR_POCL) && defined(__AVX__)
#define X86_AVX 1
typedef float __v8sf_t __attribute__((__vector_size__(32)));
typedef int __v8si_t __attribute__((__vector_size__(32)));
#if defined(__AVX2__)
#define X86_AVX2 1
#endif
#if defined(__AVX512F__)
#define X86_AVX512 1
typedef float __v16sf_t __attribute__((__vector_size__(64)));
typedef int __v16si_t __attribute__((__vector_size__(64)));
typedef __v16sf_t __v16sf_u __attribute__((aligned(4)));  // at any float address
#endif
#endif
#define MIN(a, b) ((a) < (b) ? (a) : (b))
#define MAX(a, b) ((a) > (b) ? (a) : (b))
#define CLAMP(x, lo, hi) MIN(MAX(x, lo), hi)
#define ABSV(x) MAX(x, -(x))  // fabs() is a library call under PoCL
#define LANE_F TO_FLOATV(LANE_I)

// Helpers are always inlined: PoCL's compiler otherwise keeps the larger ones (composev,
// retina_inputv, mapsv) as calls, and a call passes its floatv arguments and results through
// the stack and spills every vector register around it.
#define HOT inline __attribute__((always_inline))

// --- what lists lanes: written for 8, a float16 taken as its halves .lo and .hi --------------

HOT float8 floor8(float8 x) {
#ifdef X86_AVX
    return __builtin_astype(__builtin_ia32_roundps256(__builtin_astype(x, __v8sf_t), 9), float8);
#else
    float8 t = TO_FLOAT8(TO_INT8(x));
    return t + TO_FLOAT8(t > x);  // a true comparison is -1
#endif
}

HOT float8 sqrt8(float8 x) {
#ifdef X86_AVX
    return __builtin_astype(__builtin_ia32_sqrtps256(__builtin_astype(x, __v8sf_t)), float8);
#else
    return sqrt(x);
#endif
}

HOT float8 gather8(__global const float *p, int8 i) {
    return (float8)(p[i.s0], p[i.s1], p[i.s2], p[i.s3], p[i.s4], p[i.s5], p[i.s6], p[i.s7]);
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

HOT floatv floorv(floatv x) {
#if VEC == 8
    return floor8(x);
#elif defined(X86_AVX512)  // vrndscaleps toward -inf, all lanes, current rounding mode
    return __builtin_astype(
        __builtin_ia32_rndscaleps_mask(__builtin_astype(x, __v16sf_t), 9,
                                       __builtin_astype(x, __v16sf_t), (ushort)0xffff, 4),
        floatv);
#else
    return (floatv)(floor8(x.lo), floor8(x.hi));
#endif
}

HOT floatv sqrtv(floatv x) {
#if VEC == 8
    return sqrt8(x);
#elif defined(X86_AVX512)
    return __builtin_astype(__builtin_ia32_sqrtps512(__builtin_astype(x, __v16sf_t), 4), floatv);
#else
    return (floatv)(sqrt8(x.lo), sqrt8(x.hi));
#endif
}

HOT floatv gatherv(__global const float *p, intv i) {
#if VEC == 8
    return gather8(p, i);
#else
    return (floatv)(gather8(p, i.lo), gather8(p, i.hi));
#endif
}

// Stores lanes 0 .. n-1 of v (n <= VEC; n < VEC at the end of a row).
HOT void storev_part(__global float *p, floatv v, int n) {
#if VEC == 8
    store8_part(p, v, n);
#else
    store8_part(p, v.lo, MIN(n, 8));
    if (n > 8) store8_part(p + 8, v.hi, n - 8);
#endif
}

// Lane i: v's lane idx_i (each in [0, VEC)). One vpermps where PoCL builds for AVX2 or AVX-512
// (shuffle() is a library call under PoCL), shuffle() elsewhere.
HOT floatv lanes_at(floatv v, intv idx) {
#if VEC == 16 && defined(X86_AVX512)
    return __builtin_astype(__builtin_ia32_permvarsf512(__builtin_astype(v, __v16sf_t),
                                                        __builtin_astype(idx, __v16si_t)),
                            floatv);
#elif VEC == 8 && defined(X86_AVX2)
    return __builtin_astype(__builtin_ia32_permvarsf256(__builtin_astype(v, __v8sf_t),
                                                        __builtin_astype(idx, __v8si_t)),
                            floatv);
#else
    return shuffle(v, CAT(as_uint, VEC)(idx));
#endif
}

// A vector's lanes folded by OP: the smallest, the largest, whether any is set (min(), max()
// and any() of a vector are library calls under PoCL, see above).
#if VEC == 8
#define HALVES_FOLDED(OP, v) (v)
#else
#define HALVES_FOLDED(OP, v) OP((v).lo, (v).hi)
#endif
#define OR(a, b) ((a) | (b))
#define LANES_FOLDED(name, OP)             \
    HOT int name(intv v) {                 \
        int8 a = HALVES_FOLDED(OP, v);     \
        int4 b = OP(a.lo, a.hi);           \
        int2 c = OP(b.lo, b.hi);           \
        return OP(c.x, c.y);               \
    }
LANES_FOLDED(min_lane, MIN)
LANES_FOLDED(max_lane, MAX)
LANES_FOLDED(or_lanes, OR)
HOT int anyv(intv m) { return or_lanes(m) != 0; }  // any lane of a comparison true

// Lanes 0 .. n-1 of v to private memory and back, at the end of a row (tails only: vload and
// vstore are library calls under PoCL).
#define STOREV_PRIVATE(v, p) CAT(vstore, VEC)(v, 0, p)
#define LOADV_PRIVATE(p) CAT(vload, VEC)(0, p)

// --- G and the acuity levels in 16 bits (gazehdr/sim/lum16.py) ---------------------------------
//
// cd/m² in half a float's bytes: its exponent in 6 bits, from 2^-30, and its mantissa's top 10
// bits, rounded to nearest: 9.3e-10 .. 1.7e10 cd/m² (radiance_max 1e10) within 2^-11 of the
// value, 0 below that range (code 0). The acuity stage at 1920×1080 0.79× as long as with float
// levels and G (docs/performance.md, "Acuity"); the display's 10 bits are 2^-10 apart.
#define LUM16_EXP0 ((127 - 30) << 23)  // the float bits of 2^-30, code 0's
#define LUM16_MAX 65535

HOT ushortv to_lum16v(floatv x) {
    intv bits = AS_INTV(x);
    bits = bits < 0 ? 0 : bits;  // x < 0 (and -0): 0, before the subtraction could wrap
    intv b = (bits - LUM16_EXP0 + (1 << 12)) >> 13;  // negative (below 2^-30): 0
    return TO_USHORTV(CLAMP(b, 0, LUM16_MAX));
}

HOT floatv from_lum16v(ushortv c) {
    intv u = TO_INTV(c);
    floatv f = AS_FLOATV((u << 13) + LUM16_EXP0);
    return u == 0 ? 0.0f : f;
}

HOT ushort to_lum16(float x) {
    int b = (MAX(as_int(x), 0) - LUM16_EXP0 + (1 << 12)) >> 13;
    return (ushort)CLAMP(b, 0, LUM16_MAX);
}

HOT float from_lum16(ushort c) {
    return c == 0 ? 0.0f : as_float(((int)c << 13) + LUM16_EXP0);
}

// Pixels x .. x + VEC - 1 of a 16-bit row of n, as loadv_row.
HOT floatv lum16v_row(__global const ushort *row, int x, int n) {
    if (x + VEC <= n) return from_lum16v(LOADV_U16(row + x));
    ushort t[VEC];
    for (int i = 0; i < VEC; ++i) t[i] = row[MIN(x + i, n - 1)];
    return from_lum16v(LOADV_PRIVATE(t));
}

// Lanes 0 .. n-1 of x to a 16-bit row, as storev_part.
HOT void lum16v_store(__global ushort *p, floatv x, int n) {
    ushortv c = to_lum16v(x);
    if (n >= VEC) {
        STOREV_U16(p, c);
        return;
    }
    ushort t[VEC];
    STOREV_PRIVATE(c, t);
    for (int i = 0; i < n; ++i) p[i] = t[i];
}

// Float planes to 16-bit ones: n values a launch, VEC a work-item (the baselines' G, the
// levels of the acuity stack, the scene as its level 0).
__kernel void lum16_encode(__global const float *src, __global ushort *dst, int n) {
    int i = get_global_id(0) * VEC;
    if (i >= n) return;
    if (i + VEC <= n) {
        STOREV_U16(dst + i, to_lum16v(LOADV_G(src + i)));
        return;
    }
    for (int k = i; k < n; ++k) dst[k] = to_lum16(src[k]);
}

// -----------------------------------------------------------------------------------------------

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

// Pixels x .. x + VEC - 1 of a row of n; lanes past the end repeat the last pixel (never read
// beyond).
HOT floatv loadv_row(__global const float *row, int x, int n) {
    if (x + VEC <= n) return LOADV_G(row + x);
    return gatherv(row, MIN(x + LANE_I, n - 1));
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
    intv x0;  // first tap, unclamped
    intv a, b;
    floatv wa, wb;
} lerpv_t;

typedef struct {
    int a, b;
    float wa, wb;
} lerp1_t;

HOT lerpv_t lerpv_at(int n, floatv x, int clamp_edges) {
    floatv u = x - 0.5f;
    floatv fu = floorv(u);
    intv x0 = TO_INTV(fu);
    floatv f = u - fu;
    lerpv_t t;
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

// Bilinear value of a w-wide map at VEC x positions on one row position; `border` takes the
// weight of taps outside the map (border mode).
HOT floatv bilinearv_get(__global const float *img, int w, lerpv_t tx, lerp1_t ty,
                            float border) {
    __global const float *ra = img + ty.a * w, *rb = img + ty.b * w;
    floatv top = tx.wa * gatherv(ra, tx.a) + tx.wb * gatherv(ra, tx.b);
    floatv bot = tx.wa * gatherv(rb, tx.a) + tx.wb * gatherv(rb, tx.b);
    floatv w_in = (ty.wa + ty.wb) * (tx.wa + tx.wb);
    return ty.wa * top + ty.wb * bot + (1.0f - w_in) * border;
}

// The x part of a lookup as weights per source column: lane i takes wa at column x0_i and wb
// at x0_i + 1, and m[k] is the weight of column x0_0 + k (k < K). When the VEC positions are
// less than a column apart, K <= VEC / spacing + 2 columns serve them all, and a lookup costs
// K broadcast loads and FMAs per row instead of 2 VEC gathered loads. Returns K, 0 if K >
// XMIX_MAX.
#define XMIX_MAX 8
HOT int xmixv(lerpv_t t, floatv *m) {
    int K = LAST(t.x0) - t.x0.s0 + 2;
    if (K > XMIX_MAX) return 0;
    intv o = t.x0 - t.x0.s0;
    for (int k = 0; k < K; ++k) m[k] = (o == k ? t.wa : 0.0f) + (o == k - 1 ? t.wb : 0.0f);
    return K;
}

// The cone input (L, M, S) at retina cell (j, i): the low-res scene `down` at gaze + retinal
// offset, bilinear; a tap off the screen reads the `surround` map at the nearest screen cell
// (reference.retina_input; VEC cells at once: retina_inputv in sec2_2_afterimages.cl).
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

// The taps x0 + lane of a row of n, 0 outside it (VEC consecutive taps, border value 0).
HOT floatv row_tapsv(__global const float *row, int x0, int n) {
    if (x0 >= 0 && x0 + VEC <= n) return LOADV_G(row + x0);
    intv x = x0 + LANE_I;
    floatv v = gatherv(row, CLAMP(x, 0, n - 1));
    return (x >= 0 && x < n) ? v : 0.0f;
}

// exp and log of floatv, inline (the library's are calls, see the top), within a few ulp.
// expv is Cephes' expf (S. L. Moshier) and takes x in [-87, 88] (clamped: e^-87 = 1.6e-38
// stands for 0); logv takes x > 0 (normal numbers).
HOT floatv expv(floatv x) {
    x = CLAMP(x, -87.0f, 88.0f);
    floatv n = floorv(x * 1.44269504088896341f + 0.5f);
    x = x - n * 0.693359375f + n * 2.12194440e-4f;
    floatv z = x * x;
    floatv y = 1.9875691500e-4f;
    y = y * x + 1.3981999507e-3f;
    y = y * x + 8.3334519073e-3f;
    y = y * x + 4.1665795894e-2f;
    y = y * x + 1.6666665459e-1f;
    y = y * x + 5.0000001201e-1f;
    y = y * z + x + 1.0f;
    return y * AS_FLOATV((TO_INTV(n) + 127) << 23);
}

// x = m 2^e with m in [sqrt(1/2), sqrt(2)): sets *e and returns atanh(t) = (ln m) / 2,
// t = (m - 1) / (m + 1), |t| < 0.172: the series to t^7 is within 1e-7 relative.
HOT floatv half_log_mantissav(floatv x, intv *e) {
    intv bits = AS_INTV(x);
    *e = ((bits - 0x3f3504f3) >> 23);  // exponent after moving m into [sqrt(1/2), sqrt(2))
    floatv m = AS_FLOATV(bits - (*e << 23));
    floatv t = (m - 1.0f) / (m + 1.0f);
    floatv u = t * t;
    floatv p = u * (1.0f / 7.0f) + 1.0f / 5.0f;
    p = p * u + 1.0f / 3.0f;
    return p * u * t + t;
}

HOT floatv logv(floatv x) {
    intv e;
    floatv p = half_log_mantissav(x, &e);
    floatv fe = TO_FLOATV(e);
    return (p + p) + fe * 0.693359375f - fe * 2.12194440e-4f;
}

// ln(1 + x) for x >= 0, exact where x is tiny (logv(1 + x) would lose x to rounding): the
// series to x^4 below 0.01 (within 2e-9 relative there).
HOT floatv log1pv(floatv x) {
    floatv series = x * (1.0f - x * (0.5f - x * (1.0f / 3.0f - x * 0.25f)));
    return x < 0.01f ? series : logv(1.0f + x);
}

// 1 - e^-y for y >= 0, likewise: the series to y^4 below 0.01.
HOT floatv one_minus_exp_negv(floatv y) {
    floatv series = y * (1.0f - y * (0.5f - y * (1.0f / 6.0f - y * (1.0f / 24.0f))));
    return y < 0.01f ? series : 1.0f - expv(-y);
}

// x^y for x >= 0.
HOT floatv powv_pos(floatv x, float y) {
    return x > 0.0f ? expv(y * logv(MAX(x, FLT_MIN))) : 0.0f;
}

// log2 and 2^x of floatv to display precision, for what is only shown (compose), at about half
// the cost of logv and expv: log2 of the mantissa m in [sqrt(1/2), sqrt(2)) by a degree-5
// polynomial in m - 1 (no division), within 3.5e-5; 2^f on [-0.5, 0.5] by a degree-4 one with
// 2^0 = 1 exactly, within 3.5e-6 relative (both fitted on Chebyshev nodes; measured in float32
// by tests/test_kernel_math.py). log2_shownv takes x > 0 (normal numbers); exp2_shownv takes z
// in [-126, 126].
HOT floatv log2_shownv(floatv x) {
    intv bits = AS_INTV(x);
    intv e = (bits - 0x3f3504f3) >> 23;  // exponent after moving m into [sqrt(1/2), sqrt(2))
    floatv t = AS_FLOATV(bits - (e << 23)) - 1.0f;
    floatv p = 2.493932843e-01f;
    p = p * t - 3.894295692e-01f;
    p = p * t + 4.858239293e-01f;
    p = p * t - 7.206443548e-01f;
    p = p * t + 1.442639351e+00f;
    return p * t + TO_FLOATV(e);
}

HOT floatv exp2_shownv(floatv z) {
    floatv n = floorv(z + 0.5f);
    floatv f = z - n;
    floatv q = 9.600402787e-03f;
    q = q * f + 5.591693521e-02f;
    q = q * f + 2.402371913e-01f;
    q = q * f + 6.931219697e-01f;
    q = q * f + 1.0f;
    return q * AS_FLOATV((TO_INTV(n) + 127) << 23);
}

// ln and e^x from the same, for what is only shown (the afterimage maps): ln within 2.5e-5, e^x
// within 1e-5 relative for x in [-87, 87] and clamped there beyond.
HOT floatv log_shownv(floatv x) { return log2_shownv(x) * LN2; }
HOT floatv exp_shownv(floatv x) { return exp2_shownv(CLAMP(x, -87.0f, 87.0f) * LOG2E); }

#if VEC == 16 && defined(X86_AVX512)
// x^p for x > 0 and p in (0, 4], from p's tables in P (kernel_params.power_poly and
// power_binades: the display gamma's and the tone curve's n): x = 2^(e - 127) m with e its
// biased exponent and m in [1, 2), so x^p = 2^(p (e - 127)) m^p. With e = 32 a + b,
// 2^(p (e - 127)) is a part by b times a part by a, looked up by one vpermi2ps from 32 values
// (e's low 5 bits) and one vpermps (the host shares the bias between them so that neither
// part overflows where x^p does not, and for the gamma 1 stays exact: power_binades).
// m^p is a degree-5 polynomial in m - 1 fitted to p, exact at m = 1. Within 2.5e-6 relative
// where x^p is a normal float (tests/test_kernel_math.py); for x at most 0, NaN or Inf, finite
// (the callers select). In place of a log2 and an exp2 polynomial: compose_rgb10 0.88x as long
// for the gamma, and again 0.92x for the tone curve (docs/performance.md, "Compose"). At 8
// lanes each lookup would be a load a lane (compose 1.3x as long), so there and on GPUs the
// two polynomials stay.
HOT floatv powv_binades(__constant const float *poly, __constant const float *binades, floatv x) {
    intv e = AS_INTV(x) >> 23;  // x > 0: its biased exponent
    floatv t = AS_FLOATV((AS_INTV(x) & 0x7fffff) | 0x3f800000) - 1.0f;  // m - 1, exact
    floatv q = poly[4];
    q = q * t + poly[3];
    q = q * t + poly[2];
    q = q * t + poly[1];
    q = q * t + poly[0];
    __constant const __v16sf_u *T = (__constant const __v16sf_u *)binades;
    floatv two_b = __builtin_astype(
        __builtin_ia32_vpermi2varps512(T[0], __builtin_astype(e, __v16si_t), T[1]), floatv);
    floatv two_a = lanes_at(__builtin_astype(T[2], floatv), e >> 5);  // vpermps: a's low 4 bits
    return (1.0f + t * q) * two_b * two_a;  // two_a may be 0 or Inf, the rest finite: no NaN
}
#endif

// The display gamma x^gamma (Appendix A's v = J^gamma) for x in [0, 1], at most 1, with 0 and 1
// exact and 0 for what is not above 0: within 2.5e-6 relative where PoCL builds for AVX-512
// (powv_binades), elsewhere 2.5e-5 gamma + 4e-6 (1.5e-5 at Appendix A's 0.455, a seventh of a
// 10-bit step), for gamma in (0, 4] (tests/test_kernel_math.py).
HOT floatv gammav(__constant const params_t *P, floatv x) {
#if VEC == 16 && defined(X86_AVX512)
    floatv r = powv_binades(P->gamma_poly, P->gamma_binades, x);
#else
    floatv r = exp2_shownv(MAX(P->gamma * log2_shownv(MAX(x, FLT_MIN)), -126.0f));
#endif
    return x > 0.0f ? MIN(r, 1.0f) : 0.0f;  // never past white
}

// Naka-Rushton response (Eq. 1-2) with sigma^n = I_bar^(n-m) K^m, in logs: finite everywhere;
// no light gives exactly 0 so that black stays black.
HOT floatv tonev(__constant const params_t *P, float ln_sigma_n, floatv I) {
    floatv e = expv(MIN(ln_sigma_n - P->n * logv(MAX(I, FLT_MIN)), 80.0f));
    return I > 0.0f ? 1.0f / (1.0f + e) : 0.0f;
}

// tonev to display precision (compose, the afterimage maps): within 2e-5 relative of it, in
// [0, 1], 0 for no light. Where PoCL builds for AVX-512, as I^n / (I^n + sigma^n) with I^n from
// powv_binades (sigma^n / I^n would need I^-n, a polynomial of twice the degree); elsewhere in
// logs.
HOT floatv tonev_shown(__constant const params_t *P, float ln_sigma_n, floatv I) {
#if VEC == 16 && defined(X86_AVX512)
    floatv sigma_n = exp2_shownv((floatv)(CLAMP(ln_sigma_n * LOG2E, -125.0f, 125.0f)));
    // I^n within [0, 2^126] (Inf past float's range would make Inf / Inf), the sum a normal float
    floatv In = MIN(powv_binades(P->n_poly, P->n_binades, I), 0x1p126f);
    return I > 0.0f ? In / (In + sigma_n) : 0.0f;
#else
    floatv z = ln_sigma_n * LOG2E - P->n * log2_shownv(MAX(I, FLT_MIN));
    floatv e = exp2_shownv(CLAMP(z, -125.0f, 115.0f));  // e^-87 .. e^80, as tonev's clamps
    return I > 0.0f ? 1.0f / (1.0f + e) : 0.0f;
#endif
}

HOT float ln_sigma_n_of(__constant const params_t *P, float A) {
    return P->n_minus_m * A * LN10 + P->ln_K_m;
}

// Separable Gaussian with edge clamping. Each work-item filters VEC neighbouring pixels of
// a row as one floatv. Global size (ceil(w / VEC), h, channels).
__kernel void blur_h(__global const float *src, __global float *dst, __constant float *taps,
                     int radius, int w, int h) {
    int x = get_global_id(0) * VEC, y = get_global_id(1), c = get_global_id(2);
    if (x >= w) return;
    size_t row0 = ((size_t)c * h + y) * w;
    __global const float *row = src + row0;
    if (x >= radius && x + VEC + radius <= w) {
        floatv acc = (floatv)(0.0f);
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * LOADV_G(row + x + k);
        STOREV_G(dst + row0 + x, acc);
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
                     int radius, int w, int h, __global const uchar *d_map, __global ushort *G,
                     int level) {
    int x = get_global_id(0) * VEC, y = get_global_id(1), c = get_global_id(2);
    if (x >= w) return;
    __global const float *plane = src + (size_t)c * h * w;
    size_t out0 = ((size_t)c * h + y) * w;
    if (x + VEC <= w) {
        floatv acc = (floatv)(0.0f);
        for (int k = -radius; k <= radius; ++k)
            acc += taps[k + radius] * LOADV_G(plane + CLAMP(y + k, 0, h - 1) * w + x);
        STOREV_G(dst + out0 + x, acc);
        if (level >= 0) {
            ushortv hit = TO_USHORTV(LOADV_D(d_map + y * w + x) == (ucharv)(level + 1));
            STOREV_U16(G + out0 + x, hit ? to_lum16v(acc) : LOADV_U16(G + out0 + x));
        }
        return;
    }
    for (int i = x; i < w; ++i) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * plane[CLAMP(y + k, 0, h - 1) * w + i];
        dst[out0 + i] = acc;
        if (level >= 0 && d_map[y * w + i] == level + 1) G[out0 + i] = to_lum16(acc);
    }
}

// --- colour on VEC pixels ----------------------------------------------------------------

typedef struct {
    floatv r, g, b;
} rgbv_t;

HOT floatv dotv(__constant const float *w, floatv r, floatv g, floatv b) {
    return w[0] * r + w[1] * g + w[2] * b;
}

HOT rgbv_t matv_mul(__constant const float *m, floatv r, floatv g, floatv b) {
    rgbv_t o;
    o.r = m[0] * r + m[1] * g + m[2] * b;
    o.g = m[3] * r + m[4] * g + m[5] * b;
    o.b = m[6] * r + m[7] * g + m[8] * b;
    return o;
}
