// bowsynth's compiled core: declarations shared by the kernels and the bindings (module.cpp).
#pragma once
#include <cstddef>
#include <cstdint>

namespace bowsynth {

// Raised whenever an argument list or a kernel's meaning changes: bowsynth/core.py refuses a module of another ABI.
constexpr int ABI = 4;
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
// A control read at growing times: the segment of the previous call is kept, so the search is amortised O(1).
struct Cursor {
    Curve c;
    int64_t i = 0;
    double at(double t) {
        const int64_t n = c.n;
        while (i + 1 < n && c.t[i + 1] <= t) ++i;
        if (t <= c.t[0]) return c.v[0];
        if (i + 1 >= n) return c.v[n - 1];
        return c.v[i] + (c.v[i + 1] - c.v[i]) * (t - c.t[i]) / (c.t[i + 1] - c.t[i]);
    }
};
FdmState fdm_run(FdmState s, int64_t n0, int64_t n_out, int64_t stride, double k, Curve w2, Curve fb, Curve vb,
                 double a, double tol, int64_t maxit, double* u_out, double* eta_out);

// The ghost value u^{-1} that starts the scheme from the state (u0, p0): fdm.taylor_start.
double fdm_start(double u0, double p0, double k, double w, double fb, double vb, double a);

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
    float* q_out;           // (rows, ld_out)
    float* p_out;           // (rows, ld_out)
    int64_t ld_out;
    int64_t* fail;          // (rows, 2)
    // (B,): voice b's row of q_out, p_out and fail, so that a group of voices scattered over a render's rows writes
    // in place (rolled into arrays of its own and copied back: a chorale's render 0.202 s against 0.192 s in place)
    const int64_t* rows;
};
void roll_voices(const Rollout& r);
// The branch network and the model's states (a live voice's window: voices.cpp)
struct Net {
    int64_t m, npar, width, layers, k, grid;
    const double* ff;
    const float *Gw, *Gb, *Hw, *Hb, *Ow, *Ob;
    const double* box;
    const bool* mask;
    // Gw, Hw and Ow again in panels (pack_net), or none: the branch's products then read them as one stream each
    const float *Gp = nullptr, *Hp = nullptr, *Op = nullptr;
};
// The floats pack_net writes for N (0 where its widths do not fall in whole panels), and the packing itself: N's
// panel pointers set into buf (left none where the widths do not fit). The packed products add in the same order,
// so a voice's samples are the same bits either way.
int64_t panel_floats(const Net& N);
bool use_panels();  // false where BOWSYNTH_NO_PANELS is set (panel_floats then 0)
void pack_net(Net& N, float* buf);
int64_t live_window(const Net& N, double& q, double& p, const double* center, const double* halfrange,
                    const double* pin, double g, const float* Bq, const float* Bp, int64_t ld, int64_t n,
                    const double* eb, const double* el, float* scratch, double* zd, float* qrow, float* prow);
int64_t live_scratch(const Net& N);  // floats live_window's scratch holds (and m doubles for zd)
void roll_batch(const Rollout& r);
// The same loops built for AVX-512 (rollout.cpp compiled again with 16-float products): the entry points above hand
// over to them where use_v16() (the CPU runs AVX-512 and BOWSYNTH_NO_AVX512 is not set)
bool use_v16();
namespace v16 {
void roll_voices(const Rollout& r);
void roll_batch(const Rollout& r);
int64_t live_window(const Net& N, double& q, double& p, const double* center, const double* halfrange,
                    const double* pin, double g, const float* Bq, const float* Bp, int64_t ld, int64_t n,
                    const double* eb, const double* el, float* scratch, double* zd, float* qrow, float* prow);
}  // namespace v16
// ---- the flow at the bow's rest point (rest.cpp): a note's first samples, exact ----
// c[:7]: M (m11, m12, m21, m22), k (kq, kp) and q_s of one sample's step dtau at the linearisation (d, q_s); a row
// of rest_run's takes the radius (physics.rest_radius) in c[7]
void rest_coefficients(double d, double qs, double dtau, double* c);
// From (q, p): while the state is within the radius c[7] of (q_s, 0), its samples into oq, op and one step on (row
// c + i stride for sample i: stride 0 for one bow throughout, REST_ROW for a row each). Returns how many samples it
// wrote (n, or the first outside); (q, p) is then the state at that sample.
constexpr int64_t REST_ROW = 8;
int64_t rest_run(double& q, double& p, const double* c, int64_t stride, int64_t n, double* oq, double* op);
// ---- voices that play block by block (voices.cpp): the live engine's and a pitch curve's; the arrays' layout is
// bowsynth/engines/operator/bank.py's ----
constexpr int64_t FREE = 0, OPERATOR = 1, FDM = 2, REST = 3;  // a slot's mode
constexpr int64_t HELD = 0, CURVE = 1, LIVE = 2;    // a slot's pitch
constexpr int64_t P_F0 = 0, P_BETA = 1, P_B0 = 2, P_B1 = 3, P_BT = 4, P_D0 = 5, P_D1 = 6, P_DT = 7, P_RATE = 8,
                  P_RAMP = 9, P_COLS = 10;  // a slot's pitch parameters (voices.P_*)
constexpr int64_t WHY_OK = 0, WHY_FALLBACK = 1;
constexpr int64_t R_RADIUS = 7, R_D = 8, R_DTAU = 9, REST_COLS = 10;  // a slot's rest row after the 7 coefficients
struct Voices {
    // slots, correction rows, a window's buffer, bow inputs, trunk grid points, block, pitch-curve points
    int64_t nv, k, n_max, npar, G, bl, cp;
    int64_t *mode, *pos, *end, *why;
    double *x, *spw;  // the operator: state (nv, 2), samples per window
    int64_t* n_lo;
    float *Bq, *Bp;      // (nv, k + 3, n_max)
    double *endb, *endlin;  // (nv, 2, 2, k), (nv, 2, 6)
    const double *center, *halfrange, *pin, *gain;  // (nv, 2), (nv, 2), (nv, npar), (nv,)
    int64_t *win, *wstart, *wlen;
    float *qbuf, *pbuf;  // (nv, n_max)
    int64_t* op_end;
    double* rest;   // (nv, REST_COLS): the rest flow's step (rest_coefficients), its radius, d, and the step's dtau
    int64_t* orig;  // (nv,): the sample the operator's window partition starts from (0, or where the rest flow ends)
    Net net;
    const double* grid;  // (2, k, G): the trunk at s = (i - 1) h_grid
    double h_grid;
    const double *corr_scale, *bias;  // (2,)
    double window;
    int64_t lin_kind;  // 0 the rotation, 1 the flow linearised at rest, 2 none
    double lin_d, lin_qs, sr;
    double* fst;   // (nv, 7): u_prev, u_cur, eta, k, w, a, fb
    int64_t* fint; // (nv, 2): steps done, stride
    double *vb_t, *vb_v;  // (nv, 3)
    int64_t* nvb;
    double *fb_t, *fb_v;  // (nv, 2)
    double *su, *se;      // (nv, bl)
    int64_t* pm;
    const double *pp, *pt, *pv;  // (nv, P_COLS), (nv, cp), (nv, cp)
    const int64_t* npt;
    double *wfrac, *bdtau, *wt, *wv;  // (nv,), (nv,), (nv, 2), (nv, 2)
    double tol;
    int64_t maxit;
    float* s;  // scratch: live_scratch(net) floats, m doubles, n_max + 1 ints, 4 (n_max + 1) doubles
    double* zd;
    int64_t* idx;
    double* wts;
};
void voices_render(Voices& V, double* out, double* outp, int64_t m, double amp);
void voices_advance_to(Voices& V, int64_t v, int64_t target);
void voices_to_fdm(Voices& V, int64_t v, double q0, double p0, int64_t s);
void voices_trunk_basis(Voices& V, int64_t v, double dtau, int64_t n_lo, int64_t n_hi);
double voices_ramp(double a, double b, double t0, double length, double s);
int64_t pick_slot(const int64_t* mode, const int64_t* end, const int64_t* pos, const int64_t* start, int64_t nv);
void dc_block(const double* x, int64_t n, double r, double* state, float* y);
void polyphase(const double* x, int64_t rows, int64_t n_in, const double* w, int64_t up, int64_t K, int64_t down,
               float* y, int64_t n_out);
void resample_rows(const float* x, int64_t rows, int64_t n_in, const double* w, int64_t up, int64_t K, int64_t k0,
                   int64_t down, float* y, int64_t n_out);
void highpass_zero_phase(double* x, int64_t n, double K);

// the rollout's own tanh, cos / sin and window rule, one value at a time (for the tests)
float tanh32_of(float x);
void cos_sin_of(double z, double& c, double& s);
int64_t window_end_of(int64_t w, double spw);

}  // namespace bowsynth
