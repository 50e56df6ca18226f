// The operator's rollout loops in float32, like the trained network (the numpy reference: rollout._roll_numpy).
//
// roll_voices runs one voice after another with matrix-vector products; roll_batch advances every voice one window
// at a time with matrix-matrix products, the faster for many voices (docs/BENCHMARKS.md). A voice that fails (a
// non-finite or out-of-domain end state) stops there and writes (first sample of the window, code) into fail; the
// others go on.
//
// The products are written with GCC vector extensions, register-tiled (a tile of outputs stays in registers over
// the whole reduction, so each multiply-add costs one load): the auto-vectorised loop loaded and stored its
// outputs at every step and ran at half the speed. tanh, cos and sin are plain arithmetic (rational / Taylor
// approximations, accuracy checked in tests/test_core.py), so they vectorise where libm's one-value calls would not.
// The hot entry points are cloned for AVX2 + FMA and dispatched at load time (the wheel still runs on any x86-64).
// No -ffast-math: a NaN must reach the finiteness check.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "core.h"

// BOWSYNTH_VW: the floats a matrix product's vector holds. 8 (AVX2) in the build's main unit, whose hot entry points
// are cloned for x86-64-v3 and dispatched at load time. CMake compiles this file a second time for AVX-512
// (-march=x86-64-v4, BOWSYNTH_VW 16) into namespace bowsynth::v16; the main unit's entry points hand over to it where
// the CPU runs AVX-512 (core.h: use_v16). The element-wise loops stay on 8 floats in both.
#ifndef BOWSYNTH_VW
#define BOWSYNTH_VW 8
#endif
#if BOWSYNTH_VW == 16
#define HOT __attribute__((flatten))
#define BOWSYNTH_V16_BEGIN namespace v16 {
#define BOWSYNTH_V16_END }
#elif defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define HOT __attribute__((target_clones("arch=x86-64-v3", "default"), flatten))
#define BOWSYNTH_V16_BEGIN
#define BOWSYNTH_V16_END
#else
#define HOT
#define BOWSYNTH_V16_BEGIN
#define BOWSYNTH_V16_END
#endif

namespace bowsynth {
BOWSYNTH_V16_BEGIN
namespace {

typedef float v8 __attribute__((vector_size(32)));
// the same vector at any float's address (unaligned loads and stores; a memcpy per vector was merged by GCC into one
// block copy of the whole tile per step, through the stack)
typedef float v8u __attribute__((vector_size(32), aligned(4), may_alias));

inline v8 load8(const float* p) { return *reinterpret_cast<const v8u*>(p); }
inline void store8(float* p, v8 v) { *reinterpret_cast<v8u*>(p) = v; }
// A matrix product's vector: V floats. Products over several rows (a batch's voices, four windows' samples) take
// BOWSYNTH_VW; one row's keep 8, which 16 did not speed up (one voice at 440 / 880 Hz: 1061x / 607x against 1131x /
// 624x, benchmarks/core_speed.py on an AVX-512 Xeon: a window's ~50-100 samples leave a ragged 16-float end).
template <int V>
struct Vec {
    typedef float type __attribute__((vector_size(4 * V)));
    typedef float loose __attribute__((vector_size(4 * V), aligned(4), may_alias));
    static type load(const float* p) { return *reinterpret_cast<const loose*>(p); }
    static void store(float* p, type v) { *reinterpret_cast<loose*>(p) = v; }
};
template <int R>
constexpr int VW = R == 1 ? 8 : BOWSYNTH_VW;

// out[r, j] = bias[j] + sum_i X[r, i] W[i, j] for R rows and the CH vectors of V columns starting at j0, j0 + V, ...
// (the last one at most at N - V: a ragged end is computed as a full vector overlapping the one before). The
// R x CH tile stays in registers over the whole sum; S partial sums over i break the chain of dependent
// multiply-adds where the tile is small (one vector's K = 67 multiply-adds in a row waited on each other's latency:
// the windows' samples at 880 Hz ran at a quarter of the speed).
template <int R, int CH, int S, bool RAGGED = false, int V = VW<R>>
inline void dense_tile(const float* X, int64_t ldx, int64_t K, const float* W, int64_t ldw, int64_t N, int64_t j0,
                       const float* bias, float* out, int64_t ldo) {
    typedef Vec<V> vec;
    typedef typename vec::type vw;
    // vector c at j0 + V c, the last at N - V where the end is ragged (constant offsets otherwise: a table of
    // offsets was kept on the stack and loaded for every multiply-add)
    const int64_t last = RAGGED ? N - V - V * (CH - 1) : j0;
    int64_t col[CH];
#pragma GCC unroll 8
    for (int c = 0; c < CH; ++c) col[c] = (c == CH - 1 ? last : j0) + V * c;
    vw acc[S][R][CH];
#pragma GCC unroll 8
    for (int c = 0; c < CH; ++c) {
        const vw b0 = bias ? vec::load(bias + col[c]) : vw{};
#pragma GCC unroll 4
        for (int r = 0; r < R; ++r) {
            acc[0][r][c] = b0;
#pragma GCC unroll 4
            for (int t = 1; t < S; ++t) acc[t][r][c] = vw{};
        }
    }
    int64_t i = 0;
    for (; i + S <= K; i += S) {
#pragma GCC unroll 4
        for (int t = 0; t < S; ++t) {
            const float* w = W + (i + t) * ldw;
            float x[R];
#pragma GCC unroll 4
            for (int r = 0; r < R; ++r) x[r] = X[r * ldx + i + t];
#pragma GCC unroll 8
            for (int c = 0; c < CH; ++c) {
                const vw wc = vec::load(w + col[c]);
#pragma GCC unroll 4
                for (int r = 0; r < R; ++r) acc[t][r][c] += x[r] * wc;
            }
        }
    }
    for (; i < K; ++i) {
        const float* w = W + i * ldw;
#pragma GCC unroll 8
        for (int c = 0; c < CH; ++c) {
            const vw wc = vec::load(w + col[c]);
#pragma GCC unroll 4
            for (int r = 0; r < R; ++r) acc[0][r][c] += X[r * ldx + i] * wc;
        }
    }
#pragma GCC unroll 4
    for (int r = 0; r < R; ++r)
#pragma GCC unroll 8
        for (int c = 0; c < CH; ++c) {
            vw sum = acc[0][r][c];
#pragma GCC unroll 4
            for (int t = 1; t < S; ++t) sum += acc[t][r][c];
            vec::store(out + r * ldo + col[c], sum);
        }
}

// out (R, N) = X (R, K) @ W (K, N; rows ldw apart) + bias (N; or none), in vectors of V floats
template <int R, int V>
inline void dense_v(const float* X, int64_t ldx, int64_t K, const float* W, int64_t ldw, int64_t N, const float* bias,
                    float* out, int64_t ldo) {
    constexpr int CH = R == 1 ? 8 : (R == 2 ? 4 : 2);  // 8 accumulators + the row's vectors: within 16 registers
    if (N < V) {  // narrower than one vector (a window of fewer than V samples: f0 above ~2.5-5 kHz)
        for (int64_t j = 0; j < N; ++j)
            for (int r = 0; r < R; ++r) {
                float s = bias ? bias[j] : 0.0f;
                for (int64_t i = 0; i < K; ++i) s += X[r * ldx + i] * W[i * ldw + j];
                out[r * ldo + j] = s;
            }
        return;
    }
    int64_t j = 0;
    for (; j + V * CH <= N; j += V * CH) dense_tile<R, CH, 1, false, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
    if (j == N) return;
    const int64_t nvec = (N - j + V - 1) / V;  // the rest, its last vector ending at N
    if constexpr (R == 1) {
        switch (nvec) {
            case 1: return dense_tile<1, 1, 4, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            case 2: return dense_tile<1, 2, 4, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            case 3: return dense_tile<1, 3, 2, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            case 4: return dense_tile<1, 4, 2, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            case 5: return dense_tile<1, 5, 2, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            case 6: return dense_tile<1, 6, 2, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            case 7: return dense_tile<1, 7, 1, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
            default: return dense_tile<1, 8, 1, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);  // 8: rem > 7 V
        }
    } else {
        for (; j + V <= N; j += V) dense_tile<R, 1, 2, false, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
        if (j < N) dense_tile<R, 1, 2, true, V>(X, ldx, K, W, ldw, N, j, bias, out, ldo);
    }
}

// dense_v in the rows' vector width. Products over several rows take 16 floats in the AVX-512 unit, windows' samples
// of ~50-100 columns too: keeping 8 below 128 columns lost the batch's gain (64 voices 1766-1820x -> 1515-1601x)
template <int R>
inline void dense(const float* X, int64_t ldx, int64_t K, const float* W, int64_t ldw, int64_t N, const float* bias,
                  float* out, int64_t ldo) {
    dense_v<R, VW<R>>(X, ldx, K, W, ldw, N, bias, out, ldo);
}

// A one-row product's weights in panels of PANEL columns (dense_tile<1, 8, 1>'s tile), each panel's K rows one after
// another: the product then streams each panel from memory in order, where the rows of a (K, N) matrix sit N floats
// apart. One voice of a soft model (width 128, 90k weights read from L2 once a window) at 880 Hz: 2-8 % faster than
// the strided rows, both on 64-byte lines (benchmarks/one_voice.py); float16 panels 3-4 % more, other sums: not built.
constexpr int64_t PANEL = 64;

inline void to_panels(const float* W, int64_t K, int64_t N, float* P) {
    for (int64_t j = 0; j < N; j += PANEL)
        for (int64_t i = 0; i < K; ++i) std::memcpy(P + j * K + i * PANEL, W + i * N + j, PANEL * sizeof(float));
}

// out (N) = x (K) @ W + bias with W in panels (N a multiple of PANEL): dense<1>'s tiles in the same order, so the
// same sums to the bit
inline void dense_panels(const float* x, int64_t K, const float* P, int64_t N, const float* bias, float* out) {
    for (int64_t j = 0; j < N; j += PANEL)
        dense_tile<1, 8, 1, false, 8>(x, K, K, P + j * K, PANEL, PANEL, 0, bias ? bias + j : nullptr, out + j, N);
}

// every row of X (rows, K) through W: four rows share each load of W; the rows left over read W's panels where
// given (the same sums)
inline void dense_rows(const float* X, int64_t rows, int64_t K, const float* W, int64_t N, const float* bias,
                       float* out, const float* panels) {
    int64_t r = 0;
    for (; r + 4 <= rows; r += 4) dense<4>(X + r * K, K, K, W, N, N, bias, out + r * N, N);
    for (; r < rows; ++r)
        if (panels)
            dense_panels(X + r * K, K, panels, N, bias, out + r * N);
        else
            dense<1>(X + r * K, K, K, W, N, N, bias, out + r * N, N);
}

// tanh(x) ~ x P(x^2) / Q(x^2) on [-9, 9] (beyond, tanh is 1 to float32 precision): a rational least-squares fit,
// max error 3.4e-7 in float32. NaN passes through (every comparison with it is false).
constexpr float P0 = 0.99999993f, P1 = 0.133792701f, P2 = 0.00349369663f, P3 = 2.05850838e-05f,
                P4 = 1.33338945e-08f;
constexpr float Q1 = 0.467125736f, Q2 = 0.0258692958f, Q3 = 0.00032828556f, Q4 = 7.76546335e-07f;

// std::min(x, c) is (c < x ? c : x): a NaN x stays NaN, and GCC vectorises it as minps
inline float tanh32(float x) {
    x = std::max(std::min(x, 9.0f), -9.0f);
    const float z = x * x;
    const float p = (((P4 * z + P3) * z + P2) * z + P1) * z + P0;
    const float q = (((Q4 * z + Q3) * z + Q2) * z + Q1) * z + 1.0f;
    return std::max(std::min(x * p / q, 1.0f), -1.0f);
}

// tanh32 on 8 lanes (GCC's vector ternaries: a lane holding NaN fails every comparison and stays NaN); the
// element-wise loops are written with it because GCC left the scalar form unvectorised
inline v8 tanh8(v8 x) {
    const v8 nine = v8{} + 9.0f, one = v8{} + 1.0f;
    x = x > nine ? nine : x;
    x = x < -nine ? -nine : x;
    const v8 z = x * x;
    const v8 p = (((P4 * z + P3) * z + P2) * z + P1) * z + P0;
    const v8 q = (((Q4 * z + Q3) * z + Q2) * z + Q1) * z + 1.0f;
    v8 y = x * p / q;
    y = y > one ? one : y;
    return y < -one ? -one : y;
}

// The modified MLP's gates from g = [U-, V-, first-layer pre-activations] (3w): u - v (kept as u), v, and the first
// hidden layer h = v + tanh(z) (u - v)
inline void gates(const float* g, int64_t w, float* u, float* v, float* h) {
    int64_t j = 0;
    for (; j + 8 <= w; j += 8) {
        const v8 vv = tanh8(load8(g + w + j));
        const v8 uu = tanh8(load8(g + j)) - vv;
        store8(u + j, uu);
        store8(v + j, vv);
        store8(h + j, vv + tanh8(load8(g + 2 * w + j)) * uu);
    }
    for (; j < w; ++j) {
        const float vv = tanh32(g[w + j]);
        u[j] = tanh32(g[j]) - vv;
        v[j] = vv;
        h[j] = vv + tanh32(g[2 * w + j]) * u[j];
    }
}

// a hidden layer's activation: h = v + tanh(z) (u - v), over n values
inline void layer(const float* z, const float* u, const float* v, int64_t n, float* h) {
    int64_t j = 0;
    for (; j + 8 <= n; j += 8) store8(h + j, load8(v + j) + tanh8(load8(z + j)) * load8(u + j));
    for (; j < n; ++j) h[j] = v[j] + tanh32(z[j]) * u[j];
}

// cos and sin: reduced to [-pi, pi], then the Taylor series to r^23 (error < 1e-11 there)
constexpr double TWO_PI = 6.283185307179586;
constexpr double INV_TWO_PI = 1.0 / 6.283185307179586;
struct Taylor {
    double cos_[12], sin_[12];
    constexpr Taylor() : cos_(), sin_() {
        double f = 1.0;  // (2i)!
        for (int i = 0; i < 12; ++i) {
            if (i) f *= (2.0 * i - 1.0) * (2.0 * i);
            const double sgn = i % 2 ? -1.0 : 1.0;
            cos_[i] = sgn / f;
            sin_[i] = sgn / (f * (2.0 * i + 1.0));
        }
    }
};
constexpr Taylor TAYLOR{};

// z / 2 pi rounded to the nearest whole number by adding and removing 1.5 * 2^52 (exact for |z| < 2^51; libm's
// floor does not vectorise)
constexpr double ROUND = 6755399441055744.0;

inline void cos_sin(double z, double& c, double& s) {
    const double r = z - ((z * INV_TWO_PI + ROUND) - ROUND) * TWO_PI;
    const double r2 = r * r;
    double cc = TAYLOR.cos_[11], ss = TAYLOR.sin_[11];
#pragma GCC unroll 11
    for (int t = 10; t >= 0; --t) {
        cc = cc * r2 + TAYLOR.cos_[t];
        ss = ss * r2 + TAYLOR.sin_[t];
    }
    c = cc;
    s = ss * r;
}

typedef double v4d __attribute__((vector_size(32)));
typedef double v4du __attribute__((vector_size(32), aligned(8), may_alias));
typedef float v4f __attribute__((vector_size(16)));
typedef float v4fu __attribute__((vector_size(16), aligned(4), may_alias));

// cos_sin on 4 lanes, into float32
inline void cos_sin4(v4d z, float* c, float* s) {
    const v4d r = z - ((z * INV_TWO_PI + ROUND) - ROUND) * TWO_PI;
    const v4d r2 = r * r;
    v4d cc = v4d{} + TAYLOR.cos_[11], ss = v4d{} + TAYLOR.sin_[11];
#pragma GCC unroll 11
    for (int t = 10; t >= 0; --t) {
        cc = cc * r2 + TAYLOR.cos_[t];
        ss = ss * r2 + TAYLOR.sin_[t];
    }
    *reinterpret_cast<v4fu*>(c) = __builtin_convertvector(cc, v4f);
    *reinterpret_cast<v4fu*>(s) = __builtin_convertvector(ss * r, v4f);
}

// The branch's Fourier features of the state (q, p) and the window's bow inputs pin (none for a point model) into
// h (2m): cos then sin. z: scratch (m).
inline void features(double q, double p, const double* center, const double* halfrange, const double* ff,
                     int64_t m, const double* pin, int64_t npar, double* z, float* h) {
    const double a0 = (q - center[0]) / halfrange[0];
    const double a1 = (p - center[1]) / halfrange[1];
    for (int64_t i = 0; i < m; ++i) z[i] = a0 * ff[i] + a1 * ff[m + i];
    for (int64_t j = 0; j < npar; ++j)
        for (int64_t i = 0; i < m; ++i) z[i] += pin[j] * ff[(2 + j) * m + i];
    int64_t i = 0;
    for (; i + 4 <= m; i += 4) cos_sin4(*reinterpret_cast<const v4du*>(z + i), h + i, h + m + i);
    for (; i < m; ++i) {
        double c, s;
        cos_sin(z[i], c, s);
        h[i] = static_cast<float>(c);
        h[m + i] = static_cast<float>(s);
    }
}

inline int64_t window_end(int64_t w, double spw) {
    // first sample after window w: window w starts at the sample nearest w T, so the starts never drift from the
    // multiples of T the model trained on (rollout.window_bounds)
    return static_cast<int64_t>(std::floor(static_cast<double>(w + 1) * spw + 0.5));
}

// The window's end state in float64: the linear flow plus the correction at the last offset (oq, op already times
// the gain g, which the bias term takes here). eb: (2, k) features, el: (m11, m12, bias_q, bias_p, m22, -m21).
inline void end_state(double q0, double p0, const float* oq, const float* op, double g, const double* eb,
                      const double* el, int64_t k, double& nq, double& np) {
    nq = q0 * el[0] + p0 * el[1] + g * el[2];
    np = p0 * el[4] - q0 * el[5] + g * el[3];
    for (int64_t i = 0; i < k; ++i) {
        nq += static_cast<double>(oq[i]) * eb[i];
        np += static_cast<double>(op[i]) * eb[k + i];
    }
}

inline bool in_domain(const double* box, const bool* mask, int64_t g, double q, double p) {
    if (!(box[0] <= q && q <= box[1] && box[2] <= p && p <= box[3])) return false;
    const int64_t i = std::min(std::max(static_cast<int64_t>((q - box[0]) / (box[1] - box[0]) * g), int64_t(0)), g - 1);
    const int64_t j = std::min(std::max(static_cast<int64_t>((p - box[2]) / (box[3] - box[2]) * g), int64_t(0)), g - 1);
    return mask[i * g + j];
}

inline bool check_window(const Rollout& R, int64_t b, int64_t start, int64_t n, double nq, double np) {
    if (!(std::isfinite(nq) && std::isfinite(np))) {
        R.fail[2 * R.rows[b]] = start;
        R.fail[2 * R.rows[b] + 1] = FAIL_NONFINITE;
        return false;
    }
    if (R.check && start + n < R.n_samples && !in_domain(R.box, R.mask, R.grid, nq, np)) {
        R.fail[2 * R.rows[b]] = start + n;
        R.fail[2 * R.rows[b] + 1] = FAIL_DOMAIN;
        return false;
    }
    return true;
}

// A window's row for one side of its samples (side 0: q, 1: p): [o_q, q0, p0, g] for q, [o_p, p0, -q0, g] for p
// (the correction's k values, then the linear flow's two and the bias), against its basis Bq or Bp. x: k + 3 floats.
inline void basis_row(float* x, const float* o, int64_t k, int side, double q0, double p0, double g) {
    const float qf = static_cast<float>(q0), pf = static_cast<float>(p0);
    std::memcpy(x, o + side * k, k * sizeof(float));
    x[k] = side ? pf : qf;
    x[k + 1] = side ? -qf : pf;
    x[k + 2] = static_cast<float>(g);
}

// A window's m samples: basis_row @ Bq and @ Bp (rows ld apart). x: scratch (k + 3).
inline void samples(int64_t k, const float* Bq, const float* Bp, int64_t ld, double q0, double p0, const float* o,
                    double g, int64_t m, float* x, float* qrow, float* prow) {
    const int64_t k3 = k + 3;
    basis_row(x, o, k, 0, q0, p0, g);
    dense<1>(x, k3, k3, Bq, ld, m, nullptr, qrow, m);
    basis_row(x, o, k, 1, q0, p0, g);
    dense<1>(x, k3, k3, Bp, ld, m, nullptr, prow, m);
}

inline void samples(const Rollout& R, double q0, double p0, const float* o, double g, int64_t P, int64_t m, float* x,
                    float* qrow, float* prow) {
    const int64_t k3 = R.k + 3;
    samples(R.k, R.Bq + P * k3 * R.n_max, R.Bp + P * k3 * R.n_max, R.n_max, q0, p0, o, g, m, x, qrow, prow);
}

// Four windows' samples at once: for window slots idx[r] of the block, their basis_row @ Bq, then @ Bp, over n
// columns into Y (4, n_max), and cnt[r] of them copied to out + s0[r] (none where cnt[r] is 0: a slot repeated to
// fill the four). xs: start states (slots, 2); o: corrections (slots, 2k); g: gains.
// Each row's sums do not depend on the other rows, and n is fixed per pitch, so a window's samples are the same
// bits whichever windows share its product (a voice that stops early against one that goes on: tests/test_fallback).
inline void samples4(const Rollout& R, const int64_t* idx, const double* xs, const float* o, const double* g,
                     int64_t P, int64_t n, const int64_t* cnt, const int64_t* s0, float* X, float* Y, float* q_out,
                     float* p_out) {
    const int64_t k = R.k, k3 = k + 3, ld = R.n_max;
    const float* Bq = R.Bq + P * k3 * ld;
    const float* Bp = R.Bp + P * k3 * ld;
    for (int side = 0; side < 2; ++side) {
        for (int r = 0; r < 4; ++r)
            basis_row(X + r * k3, o + idx[r] * 2 * k, k, side, xs[2 * idx[r]], xs[2 * idx[r] + 1], g[idx[r]]);
        dense<4>(X, k3, k3, side ? Bp : Bq, ld, n, nullptr, Y, ld);
        float* out = side ? p_out : q_out;
        for (int r = 0; r < 4; ++r)
            if (cnt[r] > 0) std::memcpy(out + s0[r], Y + r * ld, cnt[r] * sizeof(float));
    }
}

// The branch at the state (q0, p0): its correction o (2k), times the gain g. s: scratch (2m + 7 width floats),
// zd: scratch (m doubles).
inline void branch(const Net& N, double q0, double p0, const double* center, const double* halfrange,
                   const double* pin, double g, float* s, double* zd, float* o) {
    const int64_t m = N.m, w = N.width, k = N.k;
    float *h = s, *gg = h + 2 * m, *u = gg + 3 * w, *v = u + w, *z = v + w, *hh = z + w;
    features(q0, p0, center, halfrange, N.ff, m, pin, N.npar, zd, h);
    if (N.Gp)
        dense_panels(h, 2 * m, N.Gp, 3 * w, N.Gb, gg);
    else
        dense<1>(h, 2 * m, 2 * m, N.Gw, 3 * w, 3 * w, N.Gb, gg, 3 * w);
    gates(gg, w, u, v, hh);  // modified MLP: h = v + tanh(z) (u - v); u is kept as u - v
    for (int64_t l = 0; l < N.layers; ++l) {
        if (N.Hp)
            dense_panels(hh, w, N.Hp + l * w * w, w, N.Hb + l * w, z);
        else
            dense<1>(hh, w, w, N.Hw + l * w * w, w, w, N.Hb + l * w, z, w);
        layer(z, u, v, w, hh);
    }
    if (N.Op)
        dense_panels(hh, w, N.Op, 2 * k, N.Ob, o);
    else
        dense<1>(hh, w, w, N.Ow, 2 * k, 2 * k, N.Ob, o, 2 * k);
    for (int64_t j = 0; j < 2 * k; ++j) o[j] = static_cast<float>(o[j] * g);
}

inline Net net_of(const Rollout& R) {
    return {R.m, R.npar, R.width, R.layers, R.k, R.grid, R.ff, R.Gw, R.Gb, R.Hw, R.Hb, R.Ow, R.Ob, R.box, R.mask};
}

// grows, never shrinks: after a process's first call of a size, no call allocates (a live engine's blocks)
template <typename T>
T* scratch(std::vector<T>& v, size_t n) {
    if (v.size() < n) v.resize(n);
    return v.data();
}
thread_local std::vector<float> ws_f;
thread_local std::vector<double> ws_d;
thread_local std::vector<int64_t> ws_i;
thread_local std::vector<float> ws_panels;

inline int64_t length_index(const Rollout& R, int64_t P, int64_t n) {
    // 0: a window of n_lo samples, 1: of n_hi (floor and ceil of spw; the bindings checked n_lo = floor(spw))
    return std::min<int64_t>(std::max<int64_t>(n - R.n_lo[P], 0), 1);
}

}  // namespace

HOT void roll_voices(const Rollout& R) {
#if BOWSYNTH_VW == 8 && defined(BOWSYNTH_HAVE_V16)
    if (use_v16()) return v16::roll_voices(R);
#endif
    const int64_t k = R.k, w = R.width, m = R.m;
    Net N = net_of(R);
    pack_net(N, scratch(ws_panels, panel_floats(N)));  // ~20 us a call, against ~3 us a window
    float* s = scratch(ws_f, 2 * m + 7 * w + 2 * k + k + 3);
    float *o = s + 2 * m + 7 * w, *x = o + 2 * k;
    double* zd = scratch(ws_d, m);
    for (int64_t b = 0; b < R.B; ++b) {
        const int64_t P = R.vidx[b];
        const double spw = R.spw[P];
        double q0 = R.x0[2 * b], p0 = R.x0[2 * b + 1];
        int64_t start = 0, win = 0;
        while (start < R.n_samples) {
            const int64_t n = window_end(win, spw) - start;
            const int64_t wi = std::min(win, R.W - 1), bw = b * R.W + wi;
            const double gw = R.gain[bw];
            branch(N, q0, p0, R.center + 2 * bw, R.halfrange + 2 * bw, R.pin + R.npar * bw, gw, s, zd, o);
            const int64_t cnt = std::min({n, R.n_samples - start, R.n_max});
            samples(R, q0, p0, o, gw, P, cnt, x, R.q_out + R.rows[b] * R.ld_out + start,
                    R.p_out + R.rows[b] * R.ld_out + start);
            const int64_t li = length_index(R, P, n);
            double nq, np;
            end_state(q0, p0, o, o + k, gw, R.endb + (P * 2 + li) * 2 * k, R.endlin + (P * 2 + li) * 6, k, nq, np);
            if (!check_window(R, b, start, n, nq, np)) break;
            q0 = nq;
            p0 = np;
            start += n;
            ++win;
        }
    }
}

// One window of a live voice (voices.cpp): roll_voices' body for one window, its n samples into qrow, prow and its
// end state into (q, p); eb, el: the end-state rows of the window's length. Returns 0, or FAIL_NONFINITE /
// FAIL_DOMAIN for an end state that is not finite / outside the model's states ((q, p) then unchanged).
HOT int64_t live_window(const Net& N, double& q, double& p, const double* center, const double* halfrange,
                        const double* pin, double g, const float* Bq, const float* Bp, int64_t ld, int64_t n,
                        const double* eb, const double* el, float* s, double* zd, float* qrow, float* prow) {
#if BOWSYNTH_VW == 8 && defined(BOWSYNTH_HAVE_V16)
    if (use_v16())
        return v16::live_window(N, q, p, center, halfrange, pin, g, Bq, Bp, ld, n, eb, el, s, zd, qrow, prow);
#endif
    const int64_t k = N.k;
    float *o = s + 2 * N.m + 7 * N.width, *x = o + 2 * k;
    branch(N, q, p, center, halfrange, pin, g, s, zd, o);
    samples(k, Bq, Bp, ld, q, p, o, g, n, x, qrow, prow);
    double nq, np;
    end_state(q, p, o, o + k, g, eb, el, k, nq, np);
    if (!(std::isfinite(nq) && std::isfinite(np))) return FAIL_NONFINITE;
    if (!in_domain(N.box, N.mask, N.grid, nq, np)) return FAIL_DOMAIN;
    q = nq;
    p = np;
    return 0;
}

constexpr int64_t BLOCK = 64;  // windows per pass of roll_batch

// All voices one window at a time. Two passes per block of BLOCK windows: the chain (branch outputs and end states
// of every voice), then the samples voice by voice, four windows to a product, so that a pitch's basis (~240 KB)
// stays in cache over the block (writing each window's samples inside the chain touched every pitch's basis per
// window: memory-bound).
HOT void roll_batch(const Rollout& R) {
#if BOWSYNTH_VW == 8 && defined(BOWSYNTH_HAVE_V16)
    if (use_v16()) return v16::roll_batch(R);
#endif
    const int64_t B = R.B, k = R.k, w = R.width, m = R.m;
    Net N = net_of(R);  // its panels for the rows left over by fours (one voice: every row)
    if (B % 4) pack_net(N, scratch(ws_panels, panel_floats(N)));
    float* H = scratch(ws_f, B * (2 * m + 3 * w + 4 * w + 2 * k + BLOCK * 2 * k) + 4 * (k + 3) + 4 * R.n_max);
    float *G = H + B * 2 * m, *U = G + B * 3 * w, *V = U + B * w, *h = V + B * w, *Z = h + B * w, *O = Z + B * w;
    float *O_blk = O + B * 2 * k, *X4 = O_blk + B * BLOCK * 2 * k, *Y4 = X4 + 4 * (k + 3);
    double* x = scratch(ws_d, B * (2 + BLOCK * 3) + m);
    double *X_blk = x + 2 * B, *G_blk = X_blk + B * BLOCK * 2, *zd = G_blk + B * BLOCK;
    int64_t* start = scratch(ws_i, B * (2 + BLOCK));
    int64_t *alive = start + B, *S_blk = alive + B;  // S_blk: each window's first sample, -1 where none was computed
    for (int64_t b = 0; b < B; ++b) {
        x[2 * b] = R.x0[2 * b];
        x[2 * b + 1] = R.x0[2 * b + 1];
        start[b] = 0;
        alive[b] = 1;
    }
    int64_t win = 0, running = B;
    while (running > 0) {
        int64_t nb = 0;
        std::fill(S_blk, S_blk + B * BLOCK, int64_t(-1));
        while (nb < BLOCK && running > 0) {
            const int64_t wi = std::min(win, R.W - 1);
            for (int64_t b = 0; b < B; ++b) {
                const int64_t bw = b * R.W + wi;
                features(x[2 * b], x[2 * b + 1], R.center + 2 * bw, R.halfrange + 2 * bw, R.ff, m,
                         R.pin + R.npar * bw, R.npar, zd, H + b * 2 * m);
            }
            dense_rows(H, B, 2 * m, R.Gw, 3 * w, R.Gb, G, N.Gp);
            for (int64_t b = 0; b < B; ++b)  // modified MLP: h = v + tanh(z) (u - v); U is kept as u - v
                gates(G + b * 3 * w, w, U + b * w, V + b * w, h + b * w);
            for (int64_t l = 0; l < R.layers; ++l) {
                dense_rows(h, B, w, R.Hw + l * w * w, w, R.Hb + l * w, Z, N.Hp ? N.Hp + l * w * w : nullptr);
                layer(Z, U, V, B * w, h);
            }
            dense_rows(h, B, w, R.Ow, 2 * k, R.Ob, O, N.Op);
            running = 0;
            for (int64_t b = 0; b < B; ++b) {
                if (!alive[b] || start[b] >= R.n_samples) continue;
                const int64_t P = R.vidx[b], bw = b * R.W + wi;
                const int64_t n = window_end(win, R.spw[P]) - start[b];
                float* o = O_blk + (b * BLOCK + nb) * 2 * k;
                const double g = R.gain[bw];
                for (int64_t j = 0; j < 2 * k; ++j) o[j] = static_cast<float>(O[b * 2 * k + j] * g);
                X_blk[(b * BLOCK + nb) * 2] = x[2 * b];
                X_blk[(b * BLOCK + nb) * 2 + 1] = x[2 * b + 1];
                G_blk[b * BLOCK + nb] = g;
                S_blk[b * BLOCK + nb] = start[b];
                const int64_t li = length_index(R, P, n);
                double nq, np;
                end_state(x[2 * b], x[2 * b + 1], o, o + k, g, R.endb + (P * 2 + li) * 2 * k,
                          R.endlin + (P * 2 + li) * 6, k, nq, np);
                if (check_window(R, b, start[b], n, nq, np)) {
                    x[2 * b] = nq;
                    x[2 * b + 1] = np;
                    start[b] += n;
                    if (start[b] < R.n_samples) ++running;
                } else {  // park the stopped voice where the network is defined, so the batch's products stay finite
                    alive[b] = 0;
                    x[2 * b] = R.center[2 * bw];
                    x[2 * b + 1] = R.center[2 * bw + 1];
                }
            }
            ++nb;
            ++win;
        }
        for (int64_t b = 0; b < B; ++b) {
            const int64_t P = R.vidx[b];
            // four windows at a time share each load of the pitch's basis (with one window, every basis value was
            // read from L2 once per multiply-add); a voice's computed windows are a prefix of the block, and a last
            // group of fewer than four repeats its last window. Every window is computed at the pitch's longer length
            const int64_t n_hi = std::min(R.n_lo[P] + 1, R.n_max);
            for (int64_t i = 0; i < nb && S_blk[b * BLOCK + i] >= 0; i += 4) {
                int64_t idx[4], s0[4], cnt[4];
                for (int r = 0; r < 4; ++r) {
                    const int64_t j = b * BLOCK + i + r;
                    if (i + r < nb && S_blk[j] >= 0) {
                        idx[r] = j;
                        s0[r] = S_blk[j];
                        const int64_t end = window_end(win - nb + i + r, R.spw[P]);
                        cnt[r] = std::min({end - s0[r], R.n_samples - s0[r], R.n_max});
                    } else {
                        idx[r] = idx[r - 1];
                        s0[r] = cnt[r] = 0;
                    }
                }
                samples4(R, idx, X_blk, O_blk, G_blk, P, n_hi, cnt, s0, X4, Y4, R.q_out + R.rows[b] * R.ld_out,
                         R.p_out + R.rows[b] * R.ld_out);
            }
        }
    }
}

#if BOWSYNTH_VW == 8
// The AVX-512 loops where the CPU runs them (AVX-512 F, VL, BW and DQ: x86-64-v4) and they were built, unless
// BOWSYNTH_NO_AVX512 is set to something other than 0 (to measure or test the AVX2 loops on such a CPU). Asked once.
bool use_v16() {
#if defined(BOWSYNTH_HAVE_V16)
    static const bool yes = [] {
        const char* off = std::getenv("BOWSYNTH_NO_AVX512");
        if (off && *off && std::strcmp(off, "0") != 0) return false;
        __builtin_cpu_init();
        return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
               __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq");
    }();
    return yes;
#else
    return false;
#endif
}
#endif

#if BOWSYNTH_VW == 8
// Unless BOWSYNTH_NO_PANELS is set to something other than 0 (to measure the strided products, or to test that the
// panels change no sample). Asked once.
bool use_panels() {
    static const bool yes = [] {
        const char* off = std::getenv("BOWSYNTH_NO_PANELS");
        return !(off && *off && std::strcmp(off, "0") != 0);
    }();
    return yes;
}

// 16 floats of slack: the panels start on a 64-byte line, so that no 8-float load of a panel row straddles two
// lines (a malloc'd buffer lies 16 bytes past one: every other load was split, and a process ran at either speed)
int64_t panel_floats(const Net& N) {
    if (!use_panels() || N.width % PANEL != 0 || (2 * N.k) % PANEL != 0) return 0;
    return 2 * N.m * 3 * N.width + N.layers * N.width * N.width + N.width * 2 * N.k + 16;
}

void pack_net(Net& N, float* buf) {
    if (panel_floats(N) == 0) return;
    const int64_t w = N.width;
    float* G = buf + (16 - (reinterpret_cast<uintptr_t>(buf) / sizeof(float)) % 16) % 16;
    float *H = G + 2 * N.m * 3 * w, *O = H + N.layers * w * w;
    to_panels(N.Gw, 2 * N.m, 3 * w, G);
    for (int64_t l = 0; l < N.layers; ++l) to_panels(N.Hw + l * w * w, w, w, H + l * w * w);
    to_panels(N.Ow, w, 2 * N.k, O);
    N.Gp = G;
    N.Hp = H;
    N.Op = O;
}
#endif

// The kernels' own tanh, cos, sin and window rule, one value at a time, for the tests (not a hot path).
float tanh32_of(float x) { return tanh32(x); }
void cos_sin_of(double z, double& c, double& s) { cos_sin(z, c, s); }
int64_t window_end_of(int64_t w, double spw) { return window_end(w, spw); }
int64_t live_scratch(const Net& N) { return 2 * N.m + 7 * N.width + 3 * N.k + 3; }

BOWSYNTH_V16_END
}  // namespace bowsynth
