/* hispo-pl: the residual MLP's LayerNorm -> GELU -> dropout, forward and backward, each one
 * pass per row (float32, rows of `cols` contiguous values; dropout as random bytes). Built
 * and loaded by native.py; the aten kernels in fast.py compute the same maths and stand in
 * where this is unavailable. Single-threaded: fast.py calls it in 1-thread processes, the
 * layout streams run in.
 *
 * GELU is the exact one, x * Phi(x); erff and expf are declared as SIMD functions so that the
 * row loops vectorise with glibc's libmvec. The dropout bytes come from random_bytes. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

float erff(float) __attribute__((simd("notinbranch"), const, nothrow));
float expf(float) __attribute__((simd("notinbranch"), const, nothrow));
float sqrtf(float) __attribute__((const, nothrow));

#define INV_SQRT2 0.70710678118654752f
#define INV_SQRT_2PI 0.39894228040143268f

/* A unit's dropout factor: scale if its random byte is >= threshold, else 0 (keep == NULL: no
 * dropout). */
#define KEEP(keep, j, threshold, scale) ((keep)[j] >= (threshold) ? (scale) : 0.f)

/* y = GELU(LayerNorm(a; g, e) [+ res]) [* dropout]; mu and rstd per row. */
void ln_gelu_drop_forward(long rows, long cols, const float *a, const float *g, const float *e,
                          const float *res, const unsigned char *keep, int threshold,
                          float scale, float eps, float *y, float *mu, float *rstd) {
    for (long i = 0; i < rows; i++) {
        const float *ai = a + i * cols;
        float *yi = y + i * cols;
        float sum = 0.f, var = 0.f;
#pragma omp simd reduction(+ : sum)
        for (long j = 0; j < cols; j++) sum += ai[j];
        const float mean = sum / cols;
#pragma omp simd reduction(+ : var)
        for (long j = 0; j < cols; j++) var += (ai[j] - mean) * (ai[j] - mean);
        const float r = 1.f / sqrtf(var / cols + eps);
        mu[i] = mean;
        rstd[i] = r;
        for (long j = 0; j < cols; j++) yi[j] = (ai[j] - mean) * r * g[j] + e[j];
        if (res) {
            const float *ri = res + i * cols;
            for (long j = 0; j < cols; j++) yi[j] += ri[j];
        }
        for (long j = 0; j < cols; j++) yi[j] = 0.5f * yi[j] * (1.f + erff(yi[j] * INV_SQRT2));
        if (keep) {
            const unsigned char *ki = keep + i * cols;
            for (long j = 0; j < cols; j++) yi[j] *= KEEP(ki, j, threshold, scale);
        }
    }
}

/* Gradients of ln_gelu_drop_forward given dy = dL/dy, the GELU's input recomputed from a:
 * dpre (written when not NULL: the gradient of LayerNorm(a) + res), da, and the column sums
 * dg, de and db (= sum of da over rows: the bias gradient of the linear layer that made a).
 * dz: cols floats of scratch. */
void ln_gelu_drop_backward(long rows, long cols, const float *dy, const unsigned char *keep,
                           int threshold, float scale, const float *a, const float *mu,
                           const float *rstd, const float *g, const float *e, const float *res,
                           float *dpre, float *da, float *dg, float *de, float *db, float *dz) {
    for (long j = 0; j < cols; j++) dg[j] = de[j] = db[j] = 0.f;
    for (long i = 0; i < rows; i++) {
        const float *dyi = dy + i * cols, *ai = a + i * cols;
        const float mean = mu[i], r = rstd[i];
        for (long j = 0; j < cols; j++) dz[j] = (ai[j] - mean) * r * g[j] + e[j];
        if (res) {
            const float *ri = res + i * cols;
            for (long j = 0; j < cols; j++) dz[j] += ri[j];
        }
        for (long j = 0; j < cols; j++) {
            const float x = dz[j];
            const float cdf = 0.5f * (1.f + erff(x * INV_SQRT2));
            const float pdf = expf(-0.5f * x * x) * INV_SQRT_2PI;
            dz[j] = dyi[j] * (cdf + x * pdf);
        }
        if (keep) {
            const unsigned char *ki = keep + i * cols;
            for (long j = 0; j < cols; j++) dz[j] *= KEEP(ki, j, threshold, scale);
        }
        if (dpre) memcpy(dpre + i * cols, dz, sizeof(float) * cols);
        float s1 = 0.f, s2 = 0.f;
#pragma omp simd reduction(+ : s1, s2)
        for (long j = 0; j < cols; j++) {
            const float xh = (ai[j] - mean) * r, dxh = dz[j] * g[j];
            dg[j] += dz[j] * xh;
            de[j] += dz[j];
            s1 += dxh;
            s2 += dxh * xh;
        }
        s1 /= cols;
        s2 /= cols;
        float *dai = da + i * cols;
        for (long j = 0; j < cols; j++) {
            const float d = r * (dz[j] * g[j] - s1 - (ai[j] - mean) * r * s2);
            dai[j] = d;
            db[j] += d;
        }
    }
}

/* n uniform random bytes: SplitMix64's words (its finaliser on seed + (i + 1) * golden gamma)
 * laid out little by little, the last word cut to fit. A counter, not a chain, so the loop
 * vectorises. */
static uint64_t splitmix64(uint64_t seed, uint64_t i) {
    uint64_t z = seed + (i + 1) * 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

void random_bytes(long n, uint64_t seed, unsigned char *out) {
    const long words = n / 8;
    for (long i = 0; i < words; i++) {
        const uint64_t z = splitmix64(seed, (uint64_t)i);
        memcpy(out + 8 * i, &z, 8);
    }
    if (n % 8) {
        const uint64_t z = splitmix64(seed, (uint64_t)words);
        memcpy(out + 8 * words, &z, (size_t)(n % 8));
    }
}
