// Voices that play block by block: the live engine's (bowsynth.live.Stream) and a pitch curve's
// (engines/operator/curve.py), on arrays prepared beforehand (engines/operator/bank.py), so that an audio callback
// allocates nothing and runs no Python per window.
//
// A window is the rollout's own (rollout.cpp: live_window, roll_voices' body) and the FDM is fdm_run itself. What
// is here is only the bookkeeping a stream needs and a whole render does not: a voice's window partition continues
// across blocks (window w of a note starts at the sample nearest w T from the note's start, as offline, so the live
// samples are the offline samples), a window's samples wait in the slot's buffer until the blocks reach them, and a
// slot changes engine (operator sustain -> FDM release) at a note-off's sample. roll_voices cannot serve: it
// restarts the partition at its first sample.
//
// Compiled without fused multiply-adds (as fdm.cpp): the hand-over's start must round as fdm.taylor_start does.
#include <algorithm>
#include <cmath>

#include "core.h"

namespace bowsynth {
namespace {

constexpr double PI = 3.141592653589793;

inline int64_t window_end(int64_t w, double spw) { return window_end_of(w, spw); }

// slot v's f0 (Hz) at the note's sample s: held, its breakpoints (times in s, linear between, held outside:
// controls.Curve), or the live bend and vibrato f0 2^((bend + depth sin(2 pi rate t)) / 12), each a ramp from its
// last change
double f0_at(const Voices& V, int64_t v, double s) {
    const double* pp = V.pp + v * P_COLS;
    if (V.pm[v] == HELD) return pp[P_F0];
    if (V.pm[v] == CURVE) {
        const double t = s / V.sr;
        const int64_t n = V.npt[v];
        const double *pt = V.pt + v * V.cp, *pv = V.pv + v * V.cp;
        if (t <= pt[0]) return pv[0];
        for (int64_t i = 0; i + 1 < n; ++i)
            if (t < pt[i + 1]) return pv[i] + (pv[i + 1] - pv[i]) * (t - pt[i]) / (pt[i + 1] - pt[i]);
        return pv[n - 1];
    }
    const double bend = voices_ramp(pp[P_B0], pp[P_B1], pp[P_BT], pp[P_RAMP], s);
    const double depth = voices_ramp(pp[P_D0], pp[P_D1], pp[P_DT], pp[P_RAMP], s);
    const double semis = bend + depth * std::sin(2.0 * PI * pp[P_RATE] * s / V.sr);
    return pp[P_F0] * std::pow(2.0, semis / 12.0);
}

// Start slot v's next window; returns its length. A moving pitch gets the window's own sample spacing: f0 at the
// window's middle (predicted with the last window's length), the window's end at the sample nearest the running sum
// of samples per window (window_end's rule with a spw per window), the basis rebuilt when the spacing changed.
int64_t next_window(Voices& V, int64_t v) {
    V.win[v] += 1;
    V.wstart[v] += V.wlen[v];
    if (V.pm[v] == HELD) {
        V.wfrac[v] = (V.win[v] + 1) * V.spw[v];
        // within the buffer whatever Python wrote (a pitch mode set back to HELD mid-note)
        V.wlen[v] = std::min(std::max(window_end(V.win[v], V.spw[v]) + V.orig[v] - V.wstart[v], int64_t(1)),
                             V.n_max - 1);
        return V.wlen[v];
    }
    const double f = f0_at(V, v, V.wstart[v] + 0.5 * V.spw[v]);
    double dtau = 2.0 * PI * f / V.sr;
    double s_w = V.window / dtau;
    if (!(s_w >= 1.0 && std::ceil(s_w) + 1 <= V.n_max)) {  // beyond what the slot was sized for: held at the edge
        s_w = s_w == s_w ? std::min(std::max(s_w, 1.0), V.n_max - 2.0) : 1.0;
        dtau = V.window / s_w;
    }
    const int64_t lo = static_cast<int64_t>(std::floor(s_w)), hi = static_cast<int64_t>(std::ceil(s_w));
    if (dtau != V.bdtau[v]) {
        voices_trunk_basis(V, v, dtau, lo, hi);
        V.bdtau[v] = dtau;
    }
    V.spw[v] = s_w;
    V.n_lo[v] = lo;
    V.wfrac[v] += s_w;
    // round(a + s_w) - round(a): floor(s_w) or ceil(s_w) samples
    const int64_t n = static_cast<int64_t>(std::floor(V.wfrac[v] + 0.5)) - V.wstart[v];
    V.wlen[v] = std::min(std::max(n, int64_t(1)), V.n_max - 1);
    return V.wlen[v];
}

// Slot v's next window: its samples into the slot's buffer, its end state into x[v]. Returns 0, FAIL_NONFINITE or
// FAIL_DOMAIN (x[v] then unchanged).
int64_t window(Voices& V, int64_t v) {
    const int64_t n = next_window(V, v);
    const int64_t k = V.k, e = std::min<int64_t>(std::max<int64_t>(n - V.n_lo[v], 0), 1);
    const int64_t rows = (k + 3) * V.n_max;
    return live_window(V.net, V.x[2 * v], V.x[2 * v + 1], V.center + 2 * v, V.halfrange + 2 * v, V.pin + V.npar * v,
                       V.gain[v], V.Bq + v * rows, V.Bp + v * rows, V.n_max, n, V.endb + (v * 2 + e) * 2 * k,
                       V.endlin + (v * 2 + e) * 6, V.s, V.zd, V.qbuf + v * V.n_max, V.pbuf + v * V.n_max);
}

// an FDM slot's next n samples into out (and p into outp), from the note's sample pos on
void play_fdm(Voices& V, int64_t v, int64_t n, double* out, double* outp, double amp) {
    double* fst = V.fst + 7 * v;
    int64_t* fint = V.fint + 2 * v;
    const int64_t stride = fint[1];
    const double k = fst[3];
    double w0 = fst[4], w1 = w0;
    double *wt = V.wt + 2 * v, *wv = V.wv + 2 * v, *fb_t = V.fb_t + 2 * v, *fb_v = V.fb_v + 2 * v;
    int64_t nw = 1;
    if (V.pm[v] != HELD) {
        // the pitch moves: w and F_B = beta w linear over this run (<= 64 samples), w^2 taken linear over it too
        // (the step's control; they differ by (dw / 2)^2 at the run's middle: < 1e-6 of w^2 for a full vibrato)
        const double beta = V.pp[v * P_COLS + P_BETA];
        w0 = 2.0 * PI * f0_at(V, v, static_cast<double>(V.pos[v]));
        w1 = 2.0 * PI * f0_at(V, v, static_cast<double>(V.pos[v] + n));
        const double t0 = fint[0] * k;
        wt[0] = t0;
        wt[1] = t0 + n * stride * k;
        wv[0] = w0 * w0;
        wv[1] = w1 * w1;
        fb_t[0] = t0;
        fb_t[1] = wt[1];
        fb_v[0] = beta * w0;
        fb_v[1] = beta * w1;
        nw = 2;
    } else {
        wt[0] = 0.0;
        wv[0] = w0 * w0;
    }
    const Curve vb{V.vb_t + 3 * v, V.vb_v + 3 * v, V.nvb[v]};
    double *su = V.su + v * V.bl, *se = V.se + v * V.bl;
    const FdmState st = fdm_run({fst[0], fst[1], fst[2]}, fint[0], n, stride, k, Curve{wt, wv, nw},
                                Curve{fb_t, fb_v, nw}, vb, fst[5], V.tol, V.maxit, su, se);
    fst[0] = st.u_prev;
    fst[1] = st.u_cur;
    fst[2] = st.eta;
    fint[0] += n * stride;
    for (int64_t i = 0; i < n; ++i) {
        const double w = w0 + (w1 - w0) * i / n;
        out[i] += amp * (w * su[i]);
    }
    if (outp) {  // p = eta + v_B at the sample's step (fdm.render_fdm)
        Cursor c{vb};
        for (int64_t i = 0; i < n; ++i) outp[i] += amp * (se[i] + c.at((fint[0] - (n - i) * stride) * k));
    }
}

// The rest flow of slot v has left its radius at the note's sample pos: the operator goes on from the state there,
// its window partition starting at that sample (as the offline render rolls out the rest of the note)
void rest_to_operator(Voices& V, int64_t v) {
    const int64_t s = V.pos[v];
    V.mode[v] = OPERATOR;
    V.orig[v] = s;
    V.win[v] = -1;
    V.wstart[v] = s;
    V.wlen[v] = 0;
    V.wfrac[v] = static_cast<double>(s);
    V.op_end[v] = -1;
}

// Slot v's rest flow for up to n samples into su, se (from the note's sample pos); returns how many it played (fewer
// when the state leaves its radius). A moving pitch steps each sample at its own dtau.
int64_t play_rest(Voices& V, int64_t v, int64_t n, double* su, double* se) {
    double* R = V.rest + REST_COLS * v;
    double* x = V.x + 2 * v;
    if (V.pm[v] == HELD) return rest_run(x[0], x[1], R, 0, n, su, se);
    int64_t done = 0;
    while (done < n) {
        const double dtau = 2.0 * PI * f0_at(V, v, static_cast<double>(V.pos[v] + done)) / V.sr;
        if (dtau != R[R_DTAU]) {
            rest_coefficients(R[R_D], R[6], dtau, R);
            R[R_DTAU] = dtau;
        }
        if (rest_run(x[0], x[1], R, 0, 1, su + done, se + done) == 0) break;
        ++done;
    }
    return done;
}

}  // namespace

double voices_ramp(double a, double b, double t0, double length, double s) {
    if (s <= t0) return a;
    if (s >= t0 + length) return b;
    return a + (b - a) * (s - t0) / length;
}

// One voice's window basis (rollout.NumpyOperator.window_basis) at sample spacing dtau, into the slot's Bq, Bp
// (k + 3, >= n_hi) and its end-state rows endb (2, 2, k), endlin (2, 6) for windows of n_lo and n_hi samples. The
// trunk's features at the offsets come from the grid by the cubic Lagrange interpolation trunk_features uses past
// TRUNK_GRID points (error below 1e-9 of the features, far under float32 rounding). Feature by feature over the
// samples, so that each row is written in order.
void voices_trunk_basis(Voices& V, int64_t v, double dtau, int64_t n_lo, int64_t n_hi) {
    const int64_t G = V.G, k = V.k, ld = V.n_max, n1 = V.n_max + 1;
    float* Bq = V.Bq + v * (k + 3) * ld;
    float* Bp = V.Bp + v * (k + 3) * ld;
    double *endb = V.endb + v * 4 * k, *endlin = V.endlin + v * 12;
    int64_t* idx = V.idx;
    double* wts = V.wts;
    for (int64_t j = 0; j <= n_hi; ++j) {
        const double s = j * dtau / V.window;
        const double u = s / V.h_grid + 1.0;
        const int64_t i = std::min(std::max(static_cast<int64_t>(std::floor(u)), int64_t(1)), G - 3);
        const double t = u - i;
        idx[j] = i - 1;
        wts[j] = -t * (t - 1.0) * (t - 2.0) / 6.0 * s;
        wts[n1 + j] = (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0 * s;
        wts[2 * n1 + j] = -(t + 1.0) * t * (t - 2.0) / 2.0 * s;
        wts[3 * n1 + j] = (t + 1.0) * t * (t - 1.0) / 6.0 * s;
    }
    auto at = [&](const double* row, int64_t j) {
        const int64_t a = idx[j];
        return wts[j] * row[a] + wts[n1 + j] * row[a + 1] + wts[2 * n1 + j] * row[a + 2] + wts[3 * n1 + j] * row[a + 3];
    };
    for (int64_t r = 0; r < 2; ++r) {
        float* B = r == 0 ? Bq : Bp;
        const double c = V.corr_scale[r];
        for (int64_t kk = 0; kk < k; ++kk) {
            const double* row = V.grid + (r * k + kk) * G;
            for (int64_t j = 0; j < n_hi; ++j) B[kk * ld + j] = static_cast<float>(c * at(row, j));
            endb[(0 * 2 + r) * k + kk] = c * at(row, n_lo);
            endb[(1 * 2 + r) * k + kk] = c * at(row, n_hi);
        }
    }
    for (int64_t j = 0; j <= n_hi; ++j) {
        const double tau = j * dtau, s = tau / V.window;
        double m11 = 1.0, m12 = 0.0, m21 = 0.0, m22 = 1.0, kq = 0.0, kp = 0.0;
        if (V.lin_kind == 0) {
            m11 = std::cos(tau);
            m12 = std::sin(tau);
            m21 = -m12;
            m22 = m11;
        } else if (V.lin_kind == 1) {  // the flow linearised at rest over tau: the rest flow's own step (rest.cpp)
            double c[7];
            rest_coefficients(V.lin_d, V.lin_qs, tau, c);
            m11 = c[0];
            m12 = c[1];
            m21 = c[2];
            m22 = c[3];
            kq = c[4];
            kp = c[5];
        }
        const double bq = V.bias[0] * V.corr_scale[0] * s + kq;
        const double bp = V.bias[1] * V.corr_scale[1] * s + kp;
        if (j < n_hi) {
            Bq[k * ld + j] = static_cast<float>(m11);
            Bq[(k + 1) * ld + j] = static_cast<float>(m12);
            Bq[(k + 2) * ld + j] = static_cast<float>(bq);
            Bp[k * ld + j] = static_cast<float>(m22);
            Bp[(k + 1) * ld + j] = static_cast<float>(-m21);
            Bp[(k + 2) * ld + j] = static_cast<float>(bp);
        }
        for (int64_t e = 0; e < 2; ++e) {
            if (j != (e == 0 ? n_lo : n_hi)) continue;
            double* el = endlin + 6 * e;
            el[0] = m11;
            el[1] = m12;
            el[2] = bq;
            el[3] = bp;
            el[4] = m22;
            el[5] = -m21;
        }
    }
}

// Compute slot v's windows until its buffer holds the note's sample `target` (a note-off's sample: the release
// starts from the sustain's state there). A window that leaves the model's states marks where the FDM takes over
// (op_end[v]: its last sample, as rollout._finish does offline; why[v] = WHY_FALLBACK).
void voices_advance_to(Voices& V, int64_t v, int64_t target) {
    float *qbuf = V.qbuf + v * V.n_max, *pbuf = V.pbuf + v * V.n_max;
    while (target >= V.wstart[v] + V.wlen[v] && V.op_end[v] < 0) {
        const int64_t last = std::max<int64_t>(V.wlen[v] - 1, 0);
        const float lq = qbuf[last], lp = pbuf[last];
        const int64_t bad = window(V, v);
        if (bad == FAIL_DOMAIN) {  // the window itself is good, its end state is not: hand over at its last sample
            V.op_end[v] = V.wstart[v] + V.wlen[v] - 1;
            V.why[v] = WHY_FALLBACK;
        } else if (bad == FAIL_NONFINITE) {  // non-finite samples: hand over from the last good sample, now
            qbuf[0] = lq;
            pbuf[0] = lp;
            V.wlen[v] = 1;
            V.op_end[v] = V.wstart[v];
            V.why[v] = WHY_FALLBACK;
        }
    }
}

// Slot v goes on with the FDM from the state (q0, p0) at the note's sample s, the FDM's time restarting at 0 there
// (the caller has set its bow breakpoints and fst[v, 3:7] = k, w, a, fb, fint[v, 1] = stride; a moving pitch takes
// w and F_B = beta w at s).
void voices_to_fdm(Voices& V, int64_t v, double q0, double p0, int64_t s) {
    double* fst = V.fst + 7 * v;
    double w = fst[4], fb = fst[6];
    if (V.pm[v] != HELD) {
        w = 2.0 * PI * f0_at(V, v, static_cast<double>(s));
        fb = V.pp[v * P_COLS + P_BETA] * w;
    }
    const double vb0 = V.vb_v[3 * v], u0 = q0 / w;
    fst[0] = fdm_start(u0, p0, fst[3], w, fb, vb0, fst[5]);
    fst[1] = u0;
    fst[2] = p0 - vb0;
    V.fint[2 * v] = 0;
}

// Add m samples of every sounding slot to out[:m] (times amp; their p to outp, if given), advancing each slot. Per
// slot: pos the note's next sample, end the note's last sample + 1 (-1 while held); a slot reaching end is freed.
void voices_render(Voices& V, double* out, double* outp, int64_t m, double amp) {
    for (int64_t v = 0; v < V.nv; ++v) {
        int64_t j = 0;
        while (j < m && V.mode[v] != FREE) {
            if (V.end[v] >= 0 && V.pos[v] >= V.end[v]) {
                V.mode[v] = FREE;
                break;
            }
            int64_t lim = m - j;
            if (V.end[v] >= 0) lim = std::min(lim, V.end[v] - V.pos[v]);
            if (V.mode[v] == REST) {
                double *su = V.su + v * V.bl, *se = V.se + v * V.bl;
                const int64_t n = std::min(lim, V.bl), done = play_rest(V, v, n, su, se);
                // float32, as the offline render stores the operator's samples
                for (int64_t i = 0; i < done; ++i) out[j + i] += amp * static_cast<double>(static_cast<float>(su[i]));
                if (outp)
                    for (int64_t i = 0; i < done; ++i)
                        outp[j + i] += amp * static_cast<double>(static_cast<float>(se[i]));
                V.pos[v] += done;
                j += done;
                if (done < n) rest_to_operator(V, v);
            } else if (V.mode[v] == OPERATOR) {
                const float *qbuf = V.qbuf + v * V.n_max, *pbuf = V.pbuf + v * V.n_max;
                if (V.op_end[v] >= 0 && V.pos[v] >= V.op_end[v]) {  // the FDM takes over, with the slot's bow
                    const int64_t a = V.pos[v] - V.wstart[v];
                    voices_to_fdm(V, v, qbuf[a], pbuf[a], V.pos[v]);
                    V.mode[v] = FDM;
                    continue;
                }
                voices_advance_to(V, v, V.pos[v]);
                int64_t stop = V.wstart[v] + V.wlen[v];
                if (V.op_end[v] >= 0) stop = std::min(stop, V.op_end[v]);
                const int64_t n = std::min(lim, stop - V.pos[v]), a = V.pos[v] - V.wstart[v];
                for (int64_t i = 0; i < n; ++i) out[j + i] += amp * qbuf[a + i];
                if (outp)
                    for (int64_t i = 0; i < n; ++i) outp[j + i] += amp * pbuf[a + i];
                V.pos[v] += n;
                j += n;
            } else {
                int64_t n = std::min(lim, V.bl);
                if (V.pm[v] != HELD) n = std::min<int64_t>(n, 64);  // short runs follow a vibrato (64: 0.001 cent)
                play_fdm(V, v, n, out + j, outp ? outp + j : nullptr, amp);
                V.pos[v] += n;
                j += n;
            }
        }
    }
}

// A free slot; else the one to steal: the releasing voice nearest its end, else the oldest.
int64_t pick_slot(const int64_t* mode, const int64_t* end, const int64_t* pos, const int64_t* start, int64_t nv) {
    for (int64_t v = 0; v < nv; ++v)
        if (mode[v] == FREE) return v;
    int64_t best = -1;
    for (int64_t v = 0; v < nv; ++v)
        if (end[v] >= 0 && (best < 0 || end[v] - pos[v] < end[best] - pos[best])) best = v;
    if (best >= 0) return best;
    best = 0;
    for (int64_t v = 0; v < nv; ++v)
        if (start[v] < start[best]) best = v;
    return best;
}

// y[:n] = the causal DC blocker y[i] = x[i] - x[i - 1] + r y[i - 1] of x[:n], its memory in state (x, y)
void dc_block(const double* x, int64_t n, double r, double* state, float* y) {
    double xp = state[0], yp = state[1];
    for (int64_t i = 0; i < n; ++i) {
        const double yi = x[i] - xp + r * yp;
        xp = x[i];
        yp = yi;
        y[i] = static_cast<float>(yi);
    }
    state[0] = xp;
    state[1] = yp;
}

// x[:n] high-passed in place by a 2nd-order Butterworth at corner K = tan(pi f_c / f_s) (bilinear), run forward then
// backward: the zero-phase |H|^2 io.audio.remove_dc asks for. Each pass starts in the filter's steady state for its
// first input (a constant gives 0 out, as scipy's filtfilt starts), so the padding's first sample is no step.
void highpass_zero_phase(double* x, int64_t n, double K) {
    if (n < 1) return;
    const double r2 = std::sqrt(2.0), norm = 1.0 / (1.0 + r2 * K + K * K);
    const double b0 = norm, b1 = -2.0 * norm, b2 = norm;
    const double a1 = 2.0 * (K * K - 1.0) * norm, a2 = (1.0 - r2 * K + K * K) * norm;
    auto pass = [&](int64_t first, int64_t step) {
        // transposed direct form II; steady state for a constant c: y = 0, z1 = -b0 c, z2 = b2 c
        const double c = x[first];
        double z1 = -b0 * c, z2 = b2 * c;
        for (int64_t i = 0, j = first; i < n; ++i, j += step) {
            const double xi = x[j], y = b0 * xi + z1;
            z1 = b1 * xi - a1 * y + z2;
            z2 = b2 * xi - a2 * y;
            x[j] = y;
        }
    };
    pass(0, 1);
    pass(n - 1, -1);
}

}  // namespace bowsynth
