// bowsynth's compiled core: declarations shared by the kernels and the bindings (module.cpp).
#pragma once
#include <cstddef>
#include <cstdint>

namespace bowsynth {

// Raised whenever an argument list or a kernel's meaning changes: bowsynth/core.py refuses a module of another ABI.
constexpr int ABI = 1;
// Why a voice stopped (bowsynth.rollout writes the same codes; a test checks they agree).
constexpr int64_t FAIL_NONFINITE = 1, FAIL_DOMAIN = 2;

// ---- FDM (fdm.cpp) ----
struct FdmState {
    double u_prev, u_cur, eta;
};
// A piecewise-linear control: breakpoints (t[i], v[i]), held outside them (controls.Curve).
struct Curve {
    const double* t;
    const double* v;
    int64_t n;
};
FdmState fdm_run(FdmState s, int64_t n0, int64_t n_out, int64_t stride, double k, Curve w2, Curve fb, Curve vb,
                 double a, double tol, int64_t maxit, double* u_out, double* eta_out);

// ---- operator rollout (rollout.cpp); the arrays' layout is documented in bowsynth/rollout.py and core.py ----
struct Rollout {
    int64_t B, n_samples, P, k, n_max, W, npar, m, width, layers, grid;
    const double* x0;       // (B, 2)
    const double* spw;      // (P,)
    const int64_t* n_lo;    // (P,)
    const int64_t* vidx;    // (B,)
    const float* Bq;        // (P, k + 3, n_max)
    const float* Bp;        // (P, k + 3, n_max)
    const double* endb;     // (P, 2, 2, k)
    const double* endlin;   // (P, 2, 6)
    const double* center;   // (B, W, 2)
    const double* halfrange;// (B, W, 2)
    const double* ff;       // (2 + npar, m)
    const double* pin;      // (B, W, npar)
    const double* gain;     // (B, W)
    const float* Gw;        // (2m, 3 width)
    const float* Gb;        // (3 width,)
    const float* Hw;        // (layers, width, width)
    const float* Hb;        // (layers, width)
    const float* Ow;        // (width, 2k)
    const float* Ob;        // (2k,)
    const double* box;      // (4,)
    const bool* mask;       // (grid, grid)
    bool check;
    float* q_out;           // (B, ld_out)
    float* p_out;           // (B, ld_out)
    int64_t ld_out;
    int64_t* fail;          // (B, 2)
};
void roll_voices(const Rollout& r);
void roll_batch(const Rollout& r);
// the rollout's own tanh, cos / sin and window rule, one value at a time (for the tests)
float tanh32_of(float x);
void cos_sin_of(double z, double& c, double& s);
int64_t window_end_of(int64_t w, double spw);

}  // namespace bowsynth
