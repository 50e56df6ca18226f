// How fast can one voice's branch run on this CPU? The branch of a range model of width W (64 Fourier features, 3
// hidden layers, 2k = 128 outputs) is a chain of one-row products, each weight read once a window: at W = 128 its
// 90k weights (352 KB) live in L2, not L1, and the products are bound by how fast the weights stream in. This times
// the core's own code (src/core/rollout.cpp, included) on random weights, one window after another, each window's
// input the last one's output (a chain, as a rollout):
//   the whole branch (features, products, activations: rollout.cpp's branch) with strided and with panel weights;
//   the products alone, strided (dense<1>) and in panels (dense_panels: the same sums);
//   the products in float16 panels, converted 16 at a time (AVX-512 where built): other sums, half the bytes.
//
//     g++ -O3 -march=native -ffp-contract=fast -fno-trapping-math -fno-math-errno -Wno-psabi -Isrc/core \
//         benchmarks/row_product.cpp -o /tmp/row_product && /tmp/row_product 128
#include <immintrin.h>

#include <chrono>
#include <cstdio>
#include <random>

#include "../src/core/rollout.cpp"

using namespace bowsynth;

#ifdef __AVX512F__
typedef float f16x __attribute__((vector_size(64)));
typedef float f16xu __attribute__((vector_size(64), aligned(4), may_alias));
// out (N) = x (K) @ W + b, W in float16 panels of 64 columns
__attribute__((noinline)) void half16(const float* x, int64_t K, const _Float16* P, int64_t N, const float* b,
                                      float* out) {
    for (int64_t j = 0; j < N; j += 64) {
        const _Float16* T = P + j * K;
        f16x acc[4];
        for (int c = 0; c < 4; ++c) acc[c] = *reinterpret_cast<const f16xu*>(b + j + 16 * c);
        for (int64_t i = 0; i < K; ++i)
#pragma GCC unroll 4
            for (int c = 0; c < 4; ++c)
                acc[c] += x[i] * (f16x)_mm512_cvtph_ps(_mm256_loadu_si256((const __m256i*)(T + i * 64 + 16 * c)));
        for (int c = 0; c < 4; ++c) *reinterpret_cast<f16xu*>(out + j + 16 * c) = acc[c];
    }
}
#endif

template <typename F>
double best_us(F f, int reps) {  // the best of 7 rounds, microseconds a window
    double best = 1e9;
    for (int round = 0; round < 7; ++round) {
        const auto t0 = std::chrono::steady_clock::now();
        for (int it = 0; it < reps; ++it) f();
        best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    return best / reps * 1e6;
}

int main(int argc, char** argv) {
    const int64_t w = argc > 1 ? atoi(argv[1]) : 128, m = 32, npar = 2, layers = 3, k = 64, reps = 20000;
    if (w < 64 || w % 64) return fprintf(stderr, "width: a multiple of 64\n"), 2;
    std::mt19937 rng(1);
    std::normal_distribution<float> nd(0.0f, 0.1f);
    // on 64-byte lines, as the package lays out the weights (basis._lined)
    auto fill = [&](int64_t n) {
        float* v = static_cast<float*>(std::aligned_alloc(64, (n * sizeof(float) + 63) / 64 * 64));
        for (int64_t i = 0; i < n; ++i) v[i] = nd(rng);
        return v;
    };
    auto Gw = fill(2 * m * 3 * w), Gb = fill(3 * w), Hw = fill(layers * w * w), Hb = fill(layers * w),
         Ow = fill(w * 2 * k), Ob = fill(2 * k);
    std::vector<double> ff(static_cast<size_t>((2 + npar) * m));
    for (auto& x : ff) x = nd(rng) * 10;
    const double box[4] = {-1, 1, -1, 1}, center[2] = {0, 0}, half[2] = {1, 1}, pin[2] = {0.2, 0.1};
    const bool mask[1] = {true};
    Net strided{m, npar, w, layers, k, 1, ff.data(), Gw, Gb, Hw, Hb, Ow, Ob, box, mask};
    Net packed = strided;
    std::vector<float> buf(panel_floats(packed));
    pack_net(packed, buf.data());
    const long macs = 2 * m * 3 * w + layers * w * w + w * 2 * k;
    std::vector<float> s(2 * m + 7 * w + 3 * k + 3), o(2 * k);
    std::vector<double> zd(m);
    printf("width %ld: %ld multiply-adds a window in the branch's products, %.0f KB of weights\n", long(w), macs,
           macs * 4 / 1024.0);
    for (const Net* N : {&strided, &packed}) {
        double q = 0.1, p = -0.05;
        const double us = best_us([&] {
            branch(*N, q, p, center, half, pin, 1.0, s.data(), zd.data(), o.data());
            q = 0.1 + 1e-9 * o[0];
        }, reps);
        printf("  the branch, %-24s %.2f us a window (%.1f GMAC/s)\n", N == &strided ? "strided" : "in panels", us,
               macs / us / 1e3);
    }
    std::vector<float> x(1024, 0.3f), y(1024);
    struct Layer { int64_t K, N; const float *W, *P, *b; };
    std::vector<Layer> net{{2 * m, 3 * w, Gw, packed.Gp, Gb}};
    for (int64_t l = 0; l < layers; ++l) net.push_back({w, w, Hw + l * w * w, packed.Hp + l * w * w, Hb});
    net.push_back({w, 2 * k, Ow, packed.Op, Ob});
    const double us0 = best_us([&] {
        for (auto& L : net) { dense<1>(x.data(), L.K, L.K, L.W, L.N, L.N, L.b, y.data(), L.N); x[0] = 0.3f + 1e-9f * y[1]; }
    }, reps);
    const double us1 = best_us([&] {
        for (auto& L : net) { dense_panels(x.data(), L.K, L.P, L.N, L.b, y.data()); x[0] = 0.3f + 1e-9f * y[1]; }
    }, reps);
    printf("  the products alone, strided     %.2f us a window (%.1f GMAC/s)\n", us0, macs / us0 / 1e3);
    printf("  the products alone, in panels   %.2f us a window (%.1f GMAC/s)\n", us1, macs / us1 / 1e3);
#ifdef __AVX512F__
    std::vector<std::vector<_Float16>> H;
    for (auto& L : net) H.emplace_back(L.P, L.P + L.K * L.N);
    const double us2 = best_us([&] {
        for (size_t l = 0; l < net.size(); ++l) {
            half16(x.data(), net[l].K, H[l].data(), net[l].N, net[l].b, y.data());
            x[0] = 0.3f + 1e-9f * y[1];
        }
    }, reps);
    printf("  the products in float16 panels  %.2f us a window (%.1f GMAC/s; other sums)\n", us2, macs / us2 / 1e3);
#endif
}
