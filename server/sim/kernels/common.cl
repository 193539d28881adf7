// Shared by every stage: the parameter block, sampling and the separable Gaussian blur.
// Maps are planar (channel, row, column); pixel i has its centre at coordinate i + 0.5.

typedef struct {
    float gamma, n, a1, a2;
    float b1[3];
    float b2[3];
    float c2, j1, j2, m1, m2;
    float w_P[3];
    float w_S[3];
    float k_s[3];
    float g, A_min, alpha_eps, Y_min;
    float ln_K_m;     // m ln K of the plateau (ours)
    float n_minus_m;  // n - m
    float H[9];       // LMS bleaching -> RGB (Appendix A)
    float rgb2lms[9];
    float lms2rgb[9];
    float rho_i[8];   // band thresholds, finest band first
    int bands;
} params_t;

#define LN10 2.302585093f

inline float3 mat3_mul(__constant const float *m, float3 v) {
    return (float3)(m[0] * v.x + m[1] * v.y + m[2] * v.z,
                    m[3] * v.x + m[4] * v.y + m[5] * v.z,
                    m[6] * v.x + m[7] * v.y + m[8] * v.z);
}

inline float dot3(__constant const float *w, float3 v) {
    return w[0] * v.x + w[1] * v.y + w[2] * v.z;
}

inline float3 load3(__global const float *img, int plane, int i) {
    return (float3)(img[i], img[plane + i], img[2 * plane + i]);
}

// Bilinear taps at continuous (x, y) on a w×h map. Taps outside the map are clamped to the
// edge, or (border mode) get weight 0 and the missing weight goes to a border value.
// Branch-free, so PoCL vectorises the per-pixel kernels that call it.
typedef struct {
    int i00, i01, i10, i11;
    float w00, w01, w10, w11, w_out;
} bilinear_t;

inline bilinear_t bilinear_at(int w, int h, float x, float y, int clamp_edges) {
    float u = x - 0.5f, v = y - 0.5f;
    float fu = floor(u), fv = floor(v);
    int x0 = (int)fu, y0 = (int)fv;
    float fx = u - fu, fy = v - fv;
    int xa = clamp(x0, 0, w - 1), xb = clamp(x0 + 1, 0, w - 1);
    int ya = clamp(y0, 0, h - 1), yb = clamp(y0 + 1, 0, h - 1);
    float ina = 1.0f, inb = 1.0f, jna = 1.0f, jnb = 1.0f;
    if (!clamp_edges) {
        ina = (x0 >= 0 && x0 < w) ? 1.0f : 0.0f;
        inb = (x0 + 1 >= 0 && x0 + 1 < w) ? 1.0f : 0.0f;
        jna = (y0 >= 0 && y0 < h) ? 1.0f : 0.0f;
        jnb = (y0 + 1 >= 0 && y0 + 1 < h) ? 1.0f : 0.0f;
    }
    bilinear_t t;
    t.i00 = ya * w + xa; t.i01 = ya * w + xb; t.i10 = yb * w + xa; t.i11 = yb * w + xb;
    t.w00 = (1.0f - fx) * (1.0f - fy) * ina * jna;
    t.w01 = fx * (1.0f - fy) * inb * jna;
    t.w10 = (1.0f - fx) * fy * ina * jnb;
    t.w11 = fx * fy * inb * jnb;
    t.w_out = 1.0f - (t.w00 + t.w01 + t.w10 + t.w11);
    return t;
}

inline float bilinear_get(__global const float *img, bilinear_t t, float border) {
    return t.w00 * img[t.i00] + t.w01 * img[t.i01] + t.w10 * img[t.i10] + t.w11 * img[t.i11]
           + t.w_out * border;
}

inline float sample_plane(__global const float *img, int w, int h, float x, float y,
                          int clamp_edges, float border) {
    return bilinear_get(img, bilinear_at(w, h, x, y, clamp_edges), border);
}

// x^y for x >= 0 as exp(y log x): PoCL vectorises exp and log, but not pow (30x slower).
inline float3 pow_pos(float3 x, float y) {
    return select((float3)(0.0f), exp(y * log(x)), isgreater(x, (float3)(0.0f)));
}

// Naka-Rushton response (Eq. 1-2) with sigma^n = I_bar^(n-m) K^m, in logs: finite everywhere;
// no light gives exactly 0 so that black stays black.
inline float tone(__constant const params_t *P, float ln_sigma_n, float I) {
    if (!(I > 0.0f)) return 0.0f;
    return 1.0f / (1.0f + exp(fmin(ln_sigma_n - P->n * log(I), 80.0f)));
}

inline float ln_sigma_n_of(__constant const params_t *P, float A) {
    return P->n_minus_m * A * LN10 + P->ln_K_m;
}

// Separable Gaussian with edge clamping. Each work-item filters 8 neighbouring pixels of a
// row as one float8: PoCL's implicit vectoriser does poorly on strided loops, explicit vectors
// run 3-5x faster on the CPU and cost nothing on a GPU. Global size (ceil(w / 8), h, channels).
#define VEC 8

__kernel void blur_h(__global const float *src, __global float *dst, __constant float *taps,
                     int radius, int w, int h) {
    int x = get_global_id(0) * VEC, y = get_global_id(1), c = get_global_id(2);
    if (x >= w) return;
    size_t row0 = ((size_t)c * h + y) * w;
    __global const float *row = src + row0;
    if (x >= radius && x + VEC + radius <= w) {
        float8 acc = (float8)(0.0f);
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * vload8(0, row + x + k);
        vstore8(acc, 0, dst + row0 + x);
        return;
    }
    for (int i = x; i < min(x + VEC, w); ++i) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * row[clamp(i + k, 0, w - 1)];
        dst[row0 + i] = acc;
    }
}

// Vertical pass. With level >= 0 it also serves the acuity bank (Eq. 14): pixels whose
// number of dropped bands d equals level + 1 copy this level into G.
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
            acc += taps[k + radius] * vload8(0, plane + clamp(y + k, 0, h - 1) * w + x);
        vstore8(acc, 0, dst + out0 + x);
        if (level >= 0) {
            int8 hit = convert_int8(vload8(0, d_map + y * w + x) == (uchar8)(level + 1));
            vstore8(select(vload8(0, G + out0 + x), acc, hit), 0, G + out0 + x);
        }
        return;
    }
    for (int i = x; i < w; ++i) {
        float acc = 0.0f;
        for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * plane[clamp(y + k, 0, h - 1) * w + i];
        dst[out0 + i] = acc;
        if (level >= 0 && d_map[y * w + i] == level + 1) G[out0 + i] = acc;
    }
}
