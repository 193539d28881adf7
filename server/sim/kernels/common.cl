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

// Bilinear sample of one plane; taps outside the map read `border`, or clamp if clamp != 0.
inline float sample_plane(__global const float *img, int w, int h, float x, float y,
                          int clamp_edges, float border) {
    float u = x - 0.5f, v = y - 0.5f;
    float fu = floor(u), fv = floor(v);
    int x0 = (int)fu, y0 = (int)fv;
    float fx = u - fu, fy = v - fv;
    float acc = 0.0f;
    for (int dy = 0; dy < 2; ++dy) {
        for (int dx = 0; dx < 2; ++dx) {
            int xi = x0 + dx, yi = y0 + dy;
            float wgt = (dx ? fx : 1.0f - fx) * (dy ? fy : 1.0f - fy);
            float val;
            if (xi >= 0 && xi < w && yi >= 0 && yi < h) {
                val = img[yi * w + xi];
            } else if (clamp_edges) {
                val = img[clamp(yi, 0, h - 1) * w + clamp(xi, 0, w - 1)];
            } else {
                val = border;
            }
            acc += wgt * val;
        }
    }
    return acc;
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

// Separable Gaussian, horizontal pass. Global size (w, h, channels); edges clamp.
// Each work-group stages its row segment plus the halo in local memory.
#define BLUR_TILE 64
__kernel void blur_h(__global const float *src, __global float *dst, __constant float *taps,
                     int radius, int w, int h, __local float *line) {
    int x = get_global_id(0), y = get_global_id(1), c = get_global_id(2);
    int lx = get_local_id(0), lw = get_local_size(0);
    int x_base = get_group_id(0) * lw;
    __global const float *row = src + ((size_t)c * h + y) * w;
    for (int i = lx; i < lw + 2 * radius; i += lw) {
        line[i] = row[clamp(x_base + i - radius, 0, w - 1)];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (x >= w) return;
    float acc = 0.0f;
    for (int k = 0; k <= 2 * radius; ++k) acc += taps[k] * line[lx + k];
    dst[((size_t)c * h + y) * w + x] = acc;
}

inline float blur_v_at(__global const float *src, __constant float *taps, int radius, int w,
                       int h, int x, int y, int c) {
    __global const float *col = src + (size_t)c * h * w + x;
    float acc = 0.0f;
    for (int k = -radius; k <= radius; ++k) acc += taps[k + radius] * col[clamp(y + k, 0, h - 1) * w];
    return acc;
}

// Separable Gaussian, vertical pass. Global size (w, h, channels).
__kernel void blur_v(__global const float *src, __global float *dst, __constant float *taps,
                     int radius, int w, int h) {
    int x = get_global_id(0), y = get_global_id(1), c = get_global_id(2);
    if (x >= w) return;
    dst[((size_t)c * h + y) * w + x] = blur_v_at(src, taps, radius, w, h, x, y, c);
}
