// Sec. 2.4 and Eq. 12: assemble the displayed value per screen pixel. Tone curve on the
// Purkinje-shifted luminance (Eq. 1, 13), mesopic hue shift, afterimage gain and bleaching
// term read at the retinal position x - gaze with the foveal fall-off, gamut, gamma.

// Largest t in [0,1] keeping Y + t (rgb - Y) inside the cube: desaturate, never flip hue.
inline float3 gamut_map(__constant const params_t *P, float3 rgb) {
    float Y = clamp(dot3(P->w_P, rgb), 0.0f, 1.0f);
    float3 d = rgb - Y;
    float t = 1.0f;
    float dd[3] = {d.x, d.y, d.z};
    for (int c = 0; c < 3; ++c) {
        if (dd[c] > 0.0f) t = fmin(t, (1.0f - Y) / dd[c]);
        else if (dd[c] < 0.0f) t = fmin(t, Y / -dd[c]);
    }
    return clamp(Y + fmax(t, 0.0f) * d, 0.0f, 1.0f);
}

__kernel void compose(__constant const params_t *P, __global const float *G,
                      __global const float *rho, __global const float *maps,
                      __global const float *A, __global float *v, int W, int H, int low_w,
                      int low_h, int cell, int grid_w, int grid_h, float gx, float gy,
                      float eyes, float fovea_sigma) {
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= W) return;
    int k = y * W + x, plane = W * H;
    float px = x + 0.5f, py = y + 0.5f;
    float3 rgb = eyes * load3(G, plane, k);
    float rc = clamp(sample_plane(rho, low_w, low_h, px / cell, py / cell, 1, 0.0f), 0.0f, 1.0f);
    float yp = dot3(P->w_P, rgb), ys = dot3(P->w_S, rgb);
    float R = tone(P, ln_sigma_n_of(P, A[0]), rc * yp + (1.0f - rc) * ys);  // Eq. 1 + Purkinje
    float3 k_s = (float3)(P->k_s[0], P->k_s[1], P->k_s[2]);
    float3 J = R * (rc * rgb / fmax(yp, P->Y_min) + (1.0f - rc) * k_s);    // hue shift
    // Afterimage maps at the retinal position of this pixel; off the grid: equilibrium.
    float mx = (px - gx) / cell + 0.5f * grid_w, my = (py - gy) / cell + 0.5f * grid_h;
    int gp = grid_w * grid_h;
    bilinear_t t = bilinear_at(grid_w, grid_h, mx, my, 0);
    float3 gain = (float3)(bilinear_get(maps, t, 1.0f), bilinear_get(maps + gp, t, 1.0f),
                           bilinear_get(maps + 2 * gp, t, 1.0f));
    float3 bleach = (float3)(bilinear_get(maps + 3 * gp, t, 0.0f),
                             bilinear_get(maps + 4 * gp, t, 0.0f),
                             bilinear_get(maps + 5 * gp, t, 0.0f));
    float dx = px - gx, dy = py - gy;
    float f = exp(-(dx * dx + dy * dy) / (2.0f * fovea_sigma * fovea_sigma));  // foveal fall-off
    float3 lms = mat3_mul(P->rgb2lms, J) * (1.0f + f * (gain - 1.0f));      // Eq. 12, alpha^j2 R
    J = mat3_mul(P->lms2rgb, lms) + f * mat3_mul(P->H, bleach);             // + bleaching via H
    J = gamut_map(P, J);
    float3 out = pow_pos(J, P->gamma);
    v[3 * k] = out.x; v[3 * k + 1] = out.y; v[3 * k + 2] = out.z;
}
