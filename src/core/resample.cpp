// The rational resampler that brings a stick-slip voice from the grid it was computed on (every window a whole number
// of samples) to the asked rate (engines/operator/grid.py): y[r, j] = sum_k w[(j down) mod up, k] x[r, (j down) div
// up + k], the filter given per phase.
#include <cmath>
#include <algorithm>
#include <cstring>
#include <vector>

#include "core.h"

namespace bowsynth {

typedef double d4 __attribute__((vector_size(32)));
typedef double d4u __attribute__((vector_size(32), aligned(8), may_alias));
typedef float f8 __attribute__((vector_size(32)));
typedef float f8u __attribute__((vector_size(32), aligned(4), may_alias));

// polyphase: output sample outer, rows inner, the phase's weights (scattered over the table) read once for all rows;
// eight partial sums in two 4-double vectors, the phase stepped by down, and K = 23 (every ratio within 10 % of 1: a
// window of 10 samples or more) compiled on its own. Any ratio; the tests' oracle for resample_rows.
template <int KK>  // KK > 0: K known when compiled
static inline void polyphase_rows(const double* x, int64_t rows, int64_t n_in, const double* wk, int64_t K,
                                  int64_t base, float* y, int64_t n_out, int64_t j) {
    const int64_t Kn = KK > 0 ? KK : K;
    for (int64_t r = 0; r < rows; ++r) {
        const double* xk = x + r * n_in + base;
        d4 a = {}, b = {};
        int64_t k = 0;
        for (; k + 8 <= Kn; k += 8) {
            a += *reinterpret_cast<const d4u*>(wk + k) * *reinterpret_cast<const d4u*>(xk + k);
            b += *reinterpret_cast<const d4u*>(wk + k + 4) * *reinterpret_cast<const d4u*>(xk + k + 4);
        }
        if (k + 4 <= Kn) {
            a += *reinterpret_cast<const d4u*>(wk + k) * *reinterpret_cast<const d4u*>(xk + k);
            k += 4;
        }
        a += b;
        double sum = (a[0] + a[2]) + (a[1] + a[3]);
        for (; k < Kn; ++k) sum += wk[k] * xk[k];
        y[r * n_out + j] = static_cast<float>(sum);
    }
}

template <int KK>
static inline void polyphase_run(const double* x, int64_t rows, int64_t n_in, const double* w, int64_t up, int64_t K,
                                 int64_t down, float* y, int64_t n_out) {
    const int64_t step = down / up, rest = down - step * up;
    int64_t base = 0, phase = 0;  // (j down) div up and mod up
    for (int64_t j = 0; j < n_out; ++j) {
        polyphase_rows<KK>(x, rows, n_in, w + phase * K, K, base, y, n_out, j);
        base += step;
        phase += rest;
        if (phase >= up) {
            phase -= up;
            ++base;
        }
    }
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
__attribute__((target_clones("arch=x86-64-v3", "default"), flatten))
#endif
void polyphase(const double* x, int64_t rows, int64_t n_in, const double* w, int64_t up, int64_t K, int64_t down,
               float* y, int64_t n_out) {
    if (K == 23)
        polyphase_run<23>(x, rows, n_in, w, up, K, down, y, n_out);
    else
        polyphase_run<0>(x, rows, n_in, w, up, K, down, y, n_out);
}

namespace {

constexpr int64_t G = 8;  // outputs per product of resample_rows' inner loop
// groups of G outputs computed side by side (2: 0.47 -> 0.43 ms for a 5 s row at 100 Hz, 4: 0.40; the loads, not
// the multiply-adds' latency, bound it from there)
constexpr int NG = 4;

// A row as the resampler reads it: x held at its last finite sample from its first non-finite one (nf; 0 if that is
// its first), with an odd continuation of k0 samples at both ends. at(i) is the padded row's sample i.
struct HeldRow {
    const float* x;
    int64_t n_in, k0, nf;
    double hold;
    double val(int64_t i) const { return i < nf ? static_cast<double>(x[i]) : hold; }
    double at(int64_t i) const {
        if (i < k0) return 2.0 * val(0) - val(k0 - i);
        i -= k0;
        if (i < n_in) return val(i);
        return 2.0 * val(n_in - 1) - val(2 * n_in - 2 - i);
    }
};

// One output, as one lane of row_body's products computes it (the taps alternately into two float32 sums, joined at
// the end), so that an output's bits do not depend on which path took it: the samples before a voice's stop are the
// same as if it had gone on (tests/test_grid.py). wc: the output's column of wt (stride ld); xs: its K inputs.
template <int KK>
inline float one_output(const float* wc, int64_t ld, const float* xs, int64_t K) {
    const int64_t Kn = KK > 0 ? KK : K;
    float a = 0.0f, b = 0.0f;
    int64_t k = 0;
    for (; k + 2 <= Kn; k += 2) {
        a += wc[k * ld] * xs[k];
        b += wc[(k + 1) * ld] * xs[k + 1];
    }
    if (k < Kn) a += wc[k * ld] * xs[k];
    return a + b;
}

// outputs [j0, j1) of a row from its padded samples (HeldRow: the ends, and a stopped voice's held stretch)
template <int KK>
inline void row_ends(const HeldRow& h, const float* wt, int64_t ld, int64_t up, int64_t K, int64_t down, float* y,
                     int64_t j0, int64_t j1) {  // y: output j0's place
    if (j0 >= j1) return;
    std::vector<float> xs(K);
    for (int64_t j = j0; j < j1; ++j) {
        const int64_t base = (j * down) / up;
        for (int64_t k = 0; k < K; ++k) xs[k] = static_cast<float>(h.at(base + k));
        y[j - j0] = one_output<KK>(wt + j % up, ld, xs.data(), K);
    }
}

// N groups of G consecutive outputs from column c of wt (y: the first output's place, xb: its first input), side by
// side: each group's two sums are a chain of K / 2 dependent multiply-adds, so one group at a time waited on the
// multiply-add's latency; the groups' chains fill each other's waits. Every lane sums as one_output does (even taps,
// odd taps, then their sum): the same bits whichever path computes an output.
template <int N, int KK>
inline void groups(const float* wt, int64_t ld, int64_t up, int64_t c, const float* xb, int64_t K, float* y) {
    const int64_t Kn = KK > 0 ? KK : K;
    const float* wc[N];
    for (int g = 0; g < N; ++g) {
        int64_t cg = c + g * G;
        while (cg >= up) cg -= up;
        wc[g] = wt + cg;
    }
    f8 a[N] = {}, b[N] = {};
    int64_t k = 0;
    for (; k + 2 <= Kn; k += 2)
        for (int g = 0; g < N; ++g) {
            a[g] += *reinterpret_cast<const f8u*>(wc[g] + k * ld) * *reinterpret_cast<const f8u*>(xb + g * G + k);
            b[g] += *reinterpret_cast<const f8u*>(wc[g] + (k + 1) * ld) *
                    *reinterpret_cast<const f8u*>(xb + g * G + k + 1);
        }
    if (k < Kn)
        for (int g = 0; g < N; ++g)
            a[g] += *reinterpret_cast<const f8u*>(wc[g] + k * ld) * *reinterpret_cast<const f8u*>(xb + g * G + k);
    for (int g = 0; g < N; ++g) {
        a[g] += b[g];
        std::memcpy(y + g * G, &a[g], sizeof a[g]);
    }
}

template <int KK>
inline void row_body(const float* x, const float* wt, int64_t ld, int64_t up, int64_t K, int64_t down, float* y,
                     int64_t j0, int64_t j1) {  // y: output j0's place
    // outputs [j0, j1) read x itself (x here: the padded row's index), so no buffer is built. Eight consecutive
    // outputs whose phases do not wrap read eight consecutive inputs at each tap (the ratio in [1/2, 1): the grids'
    // own), so they are one product of the tap's eight weights (wt: the weights in output order, tap-major) with
    // the inputs: K vector multiply-adds for eight outputs, against K / 4 and a horizontal sum each in float64
    // before (0.85 ms for 5 s of two rows at 100 Hz against 1.6; float32 is the network's precision)
    const int64_t step = down / up, rest = down - step * up;
    int64_t base = (j0 * down) / up, phase = (j0 * down) % up, c = j0 % up;
    int64_t j = j0;
    while (j < j1) {
        // as many outputs at once as read consecutive inputs without a phase wrap: NG groups, one, or one output
        const int64_t n = step != 1                                                     ? 1
                          : j + NG * G <= j1 && phase + (NG * G - 1) * rest < up ? NG * G
                          : j + G <= j1 && phase + (G - 1) * rest < up           ? G
                                                                                  : 1;
        if (n == NG * G)
            groups<NG, KK>(wt, ld, up, c, x + base, K, y + (j - j0));
        else if (n == G)
            groups<1, KK>(wt, ld, up, c, x + base, K, y + (j - j0));
        else
            y[j - j0] = one_output<KK>(wt + c, ld, x + base, K);
        j += n;
        base += n == 1 ? step : n;
        phase += n * rest;
        c += n;
        while (phase >= up) {
            phase -= up;
            ++base;
        }
        while (c >= up) c -= up;
    }
}

}  // namespace

// Rows (rows, n_in) of a voice's float32 grid samples resampled into y (rows, n_out), as engines.operator.grid
// .to_output did in numpy: each row held at its last finite sample from its first non-finite one (0 if that is its
// first), with an odd continuation of k0 samples at both ends (computed in float64), summed in float32. Only the
// outputs that reach past either end of x's finite samples read that padded row (HeldRow); the rest read x where it
// lies. Before, the row was first copied to a float64 buffer (3.5 MB for 5 s at 100 Hz, on fresh pages in every
// render: to_output took 2.9 ms in a render where it took 1.6 ms on warm memory) and each output was one 23-tap dot
// product.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
__attribute__((target_clones("arch=x86-64-v3", "default"), flatten))
#endif
void resample_rows(const float* x, int64_t rows, int64_t n_in, const double* w, int64_t up, int64_t K, int64_t k0,
                   int64_t down, float* y, int64_t n_out) {
    const int64_t ld = up + G;
    std::vector<float> wt(K * ld);  // wt[k, c] = w[(c mod up) down mod up, k]: the phases in output order
    for (int64_t c = 0; c < ld; ++c) {
        const int64_t phase = ((c % up) * down) % up;
        for (int64_t k = 0; k < K; ++k) wt[k * ld + c] = static_cast<float>(w[phase * K + k]);
    }
    // the outputs that read only x's finite samples: base_j in [k0, k0 + nf - K], base_j = (j down) div up
    auto first_at = [&](int64_t b) { return std::min(n_out, (b * up + down - 1) / down); };  // first j: base_j >= b
    for (int64_t r = 0; r < rows; ++r) {
        const float* xr = x + r * n_in;
        int64_t nf = 0;  // first non-finite: 64 samples at a time (x - x is 0 for a finite x, NaN for the rest)
        for (; nf + 64 <= n_in; nf += 64) {
            f8 z = {};
            for (int i = 0; i < 64; i += 8) {
                const f8 v = *reinterpret_cast<const f8u*>(xr + nf + i);
                z += v - v;
            }
            bool finite = true;
            for (int i = 0; i < 8; ++i) finite = finite && z[i] == 0.0f;
            if (!finite) break;
        }
        while (nf < n_in && std::isfinite(xr[nf])) ++nf;
        const HeldRow h{xr, n_in, k0, nf, nf > 0 ? static_cast<double>(xr[nf - 1]) : 0.0};
        float* yr = y + r * n_out;
        const int64_t j0 = first_at(k0), j1 = std::max(j0, first_at(k0 + nf - K + 1));
        // outputs [a, b) into out[0 .. b - a)
        auto span = [&](int64_t a, int64_t b, float* out) {
            const int64_t e0 = std::min(b, j0), b0 = std::max(a, j0), b1 = std::max(b0, std::min(b, j1));
            const int64_t e1 = std::max(a, b1);
            if (K == 23) {
                row_ends<23>(h, wt.data(), ld, up, K, down, out, a, e0);
                row_body<23>(xr - k0, wt.data(), ld, up, K, down, out + (b0 - a), b0, b1);
                row_ends<23>(h, wt.data(), ld, up, K, down, out + (e1 - a), e1, b);
            } else {
                row_ends<0>(h, wt.data(), ld, up, K, down, out, a, e0);
                row_body<0>(xr - k0, wt.data(), ld, up, K, down, out + (b0 - a), b0, b1);
                row_ends<0>(h, wt.data(), ld, up, K, down, out + (e1 - a), e1, b);
            }
        };
        if (yr != xr) {
            span(0, n_out, yr);
            continue;
        }
        // in place (the binding allows it for one row with down >= up): output j reads x from (j down) div up - k0
        // >= j - k0 on, so a chunk of C outputs is written back once the next chunk is computed, when no output
        // left reads it. A render's grid rows become its output rows, with no fresh array (whose first touch cost
        // ~0.8 ms of a 5 s render's 5)
        const int64_t C = std::max<int64_t>(4096, 4 * (k0 + G));
        std::vector<float> buf(2 * C);
        int64_t pending = -1;  // the chunk computed and not yet written back
        for (int64_t a = 0; a < n_out; a += C) {
            float* cur = buf.data() + ((a / C) % 2) * C;
            span(a, std::min(a + C, n_out), cur);
            if (pending >= 0)
                std::memcpy(yr + pending, buf.data() + ((pending / C) % 2) * C, C * sizeof(float));
            pending = a;
        }
        if (pending >= 0)
            std::memcpy(yr + pending, buf.data() + ((pending / C) % 2) * C, (n_out - pending) * sizeof(float));
    }
}

}  // namespace bowsynth
