// The FDM's loop: Bilbao's scheme for the bowed mass, Newton on the relative velocity (documented in bowsynth/fdm.py).
// Compiled without fused multiply-adds, every operation in the numpy reference's order (fdm._solve_eta_bracketed,
// physics.phi), so that the compiled and numpy paths agree to the bit: a stick-slip release amplifies a last-bit
// difference to 1e-5 within 0.1 s.
#include <algorithm>
#include <cmath>

#include "core.h"

namespace bowsynth {
namespace {

inline double phi(double x, double a) { return std::sqrt(2.0 * a) * x * std::exp(-a * x * x + 0.5); }
inline double dphi(double x, double a) {
    return std::sqrt(2.0 * a) * std::exp(-a * x * x + 0.5) * (1.0 - 2.0 * a * x * x);
}

// Root of c x + fb phi(x) + b (increasing in x under the uniqueness bound), Newton kept inside a bracket.
inline double solve_eta(double guess, double b, double c, double fb, double a, double tol, int64_t maxit) {
    double lo = (-b - fb) / c;
    double hi = (-b + fb) / c;
    double x = std::min(std::max(guess, lo), hi);
    for (int64_t it = 0; it < maxit; ++it) {
        const double fx = c * x + fb * phi(x, a) + b;
        if (fx > 0.0)
            hi = x;
        else
            lo = x;
        const double d = c + fb * dphi(x, a);
        double xn = d > 0.0 ? x - fx / d : 0.5 * (lo + hi);
        if (!(lo <= xn && xn <= hi)) xn = 0.5 * (lo + hi);
        if (std::fabs(xn - x) <= tol) return xn;
        x = xn;
    }
    return x;
}

}  // namespace

double fdm_start(double u0, double p0, double k, double w, double fb, double vb, double a) {
    return u0 - k * p0 - 0.5 * k * k * (w * w * u0 + fb * phi(p0 - vb, a));
}

// Steps n0, n0 + 1, ... at t = n k; w^2, the bow force and speed follow their breakpoints step by step (a pitch
// curve is w^2's). Writes u and eta at every stride-th step; returns the state to continue from.
FdmState fdm_run(FdmState s, int64_t n0, int64_t n_out, int64_t stride, double k, Curve w2c, Curve fbc, Curve vbc,
                 double a, double tol, int64_t maxit, double* u_out, double* eta_out) {
    const double c = 2.0 / k;
    const double ck = 2.0 / (k * k);
    Cursor w2{w2c}, fb{fbc}, vb{vbc};
    double u_prev = s.u_prev, u_cur = s.u_cur, eta = s.eta;
    for (int64_t j = 0; j < n_out; ++j) {
        for (int64_t st = 0; st < stride; ++st) {
            const double t = static_cast<double>(n0 + j * stride + st) * k;
            const double f = fb.at(t), v = vb.at(t), ww = w2.at(t);
            const double b = c * v + ck * (u_prev - u_cur) + ww * u_cur;
            eta = solve_eta(eta, b, c, f, a, tol, maxit);
            if (st == 0) {
                u_out[j] = u_cur;
                eta_out[j] = eta;
            }
            const double u_next = u_prev + 2.0 * k * (eta + v);
            u_prev = u_cur;
            u_cur = u_next;
        }
    }
    return {u_prev, u_cur, eta};
}

}  // namespace bowsynth
