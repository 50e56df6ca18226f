// The bowed mass near its bow's rest point, exactly: q' = p, p' = -(q - q_s) - d p (physics.rest_linearisation),
// one sample at a time, x <- M x + k with M = exp(A dtau), k = (I - M) (q_s, 0) (physics.flow_coefficients). A note
// from rest grows from here by a factor exp(-d dtau / 2) a sample: where d is small (light, slow bows: onsets of
// 0.2-2 s) the network's small absolute errors near rest set the onset's time (the operator spoke 50-700 ms early or
// late), while this flow is exact until the friction's slope changes over the swing (physics.rest_radius). The
// offline renderer (engines/operator/onset.py) and the live voices (voices.cpp) run this same loop, so the two agree.
#include <algorithm>
#include <cmath>

#include "core.h"

namespace bowsynth {

void rest_coefficients(double d, double qs, double dtau, double* c) {
    // e^(-d tau / 2) times (cos, sin / wd) of wd tau for an underdamped bow (|d| < 2), (cosh, sinh / wd) for an
    // overdamped one, as the two real modes' exponentials (a heavy, slow bow: d up to ~30, whose cosh alone would
    // overflow over a long step); both tend to (1, tau) at critical damping.
    const double z = 1.0 - 0.25 * d * d;
    double ec, es;
    if (z >= 0.0) {
        const double wd = std::sqrt(std::max(z, 1e-30)), e = std::exp(-0.5 * d * dtau);
        ec = e * std::cos(wd * dtau);
        es = e * std::sin(wd * dtau) / wd;
    } else {
        const double wd = std::sqrt(-z);
        const double slow = std::exp((wd - 0.5 * d) * dtau), fast = std::exp((-wd - 0.5 * d) * dtau);
        ec = 0.5 * (slow + fast);
        es = 0.5 * (slow - fast) / wd;
    }
    c[0] = ec + 0.5 * d * es;
    c[1] = es;
    c[2] = -es;
    c[3] = ec - 0.5 * d * es;
    c[4] = qs * (1.0 - c[0]);
    c[5] = -qs * c[2];
    c[6] = qs;
}

int64_t rest_run(double& q, double& p, const double* c, int64_t stride, int64_t n, double* oq, double* op) {
    for (int64_t i = 0; i < n; ++i) {
        const double* ci = c + i * stride;
        const double dq = q - ci[6];
        if (!(dq * dq + p * p <= ci[7] * ci[7])) return i;  // NaN leaves too
        oq[i] = q;
        op[i] = p;
        const double qn = ci[0] * q + ci[1] * p + ci[4];
        p = ci[2] * q + ci[3] * p + ci[5];
        q = qn;
    }
    return n;
}

}  // namespace bowsynth
