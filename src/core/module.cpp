// Python bindings of the compiled core (bowsynth._core). Every array is checked here, before the GIL is released:
// a wrong dtype, order or rank is nanobind's TypeError (arrays are never converted: an output written into a
// converted copy would be lost), a wrong shape or an inconsistent size a ValueError naming the argument. The kernels
// index nothing they were not given.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <cmath>
#include <string>
#include <tuple>

#include "core.h"

namespace nb = nanobind;
using namespace nb::literals;

#ifndef BOWSYNTH_CORE_DIGEST
#define BOWSYNTH_CORE_DIGEST "unknown"
#endif

template <typename T, size_t N>
using In = nb::ndarray<const T, nb::ndim<N>, nb::c_contig, nb::device::cpu>;
template <typename T, size_t N>
using Out = nb::ndarray<T, nb::ndim<N>, nb::c_contig, nb::device::cpu>;

namespace {

std::string dims(std::initializer_list<int64_t> s) {
    std::string out = "(";
    size_t i = 0;
    for (int64_t v : s) out += std::to_string(v) + (++i < s.size() ? ", " : "");
    return out + (s.size() == 1 ? ",)" : ")");
}

template <typename A>
std::string shape_of(const A& a) {
    std::string out = "(";
    for (size_t i = 0; i < a.ndim(); ++i) out += std::to_string(a.shape(i)) + (i + 1 < a.ndim() ? ", " : "");
    return out + (a.ndim() == 1 ? ",)" : ")");
}

template <typename A>
void shape(const char* fn, const char* name, const A& a, std::initializer_list<int64_t> want) {
    size_t i = 0;
    bool ok = a.ndim() == want.size();
    for (int64_t v : want) ok = ok && static_cast<int64_t>(a.shape(i++)) == v;
    if (!ok)
        throw nb::value_error((std::string(fn) + ": " + name + " has shape " + shape_of(a) + ", expected " + dims(want))
                                  .c_str());
}

void need(bool ok, const std::string& what) {
    if (!ok) throw nb::value_error(what.c_str());
}

bowsynth::Curve curve(const char* name, const In<double, 1>& t, const In<double, 1>& v) {
    need(t.shape(0) >= 1 && t.shape(0) == v.shape(0),
         std::string("fdm_run: ") + name + " needs as many times as values, at least one (got " +
             std::to_string(t.shape(0)) + " and " + std::to_string(v.shape(0)) + ")");
    for (size_t i = 1; i < t.shape(0); ++i)
        need(t(i) > t(i - 1), std::string("fdm_run: ") + name + "'s times must increase");
    return {t.data(), v.data(), static_cast<int64_t>(t.shape(0))};
}

std::tuple<double, double, double> fdm_run(double u_prev, double u_cur, double eta, int64_t n0, int64_t n_out,
                                           int64_t stride, double k, In<double, 1> w2_t, In<double, 1> w2_v,
                                           In<double, 1> fb_t, In<double, 1> fb_v, In<double, 1> vb_t,
                                           In<double, 1> vb_v, double a, double tol, int64_t maxit,
                                           Out<double, 1> u_out, Out<double, 1> eta_out) {
    need(n0 >= 0 && n_out >= 0 && stride >= 1 && maxit >= 1,
         "fdm_run: needs n0 >= 0, n_out >= 0, stride >= 1, maxit >= 1");
    need(std::isfinite(k) && k > 0, "fdm_run: the step k must be a positive number");
    need(static_cast<int64_t>(u_out.shape(0)) >= n_out && static_cast<int64_t>(eta_out.shape(0)) >= n_out,
         "fdm_run: u_out and eta_out must hold n_out values");
    const auto w2 = curve("w2", w2_t, w2_v), fb = curve("fb", fb_t, fb_v), vb = curve("vb", vb_t, vb_v);
    bowsynth::FdmState s{u_prev, u_cur, eta};
    {
        nb::gil_scoped_release unlocked;
        s = bowsynth::fdm_run(s, n0, n_out, stride, k, w2, fb, vb, a, tol, maxit, u_out.data(), eta_out.data());
    }
    return {s.u_prev, s.u_cur, s.eta};
}

using Roll = void (*)(const bowsynth::Rollout&);

template <Roll kernel>
void roll(const char* fn, In<double, 2> x0, int64_t n_samples, In<double, 1> spw, In<int64_t, 1> n_lo,
          In<int64_t, 1> vidx, In<float, 3> Bq, In<float, 3> Bp, In<double, 4> endb, In<double, 3> endlin,
          In<double, 3> center, In<double, 3> halfrange, In<double, 2> ff, In<double, 3> pin, In<double, 2> gain,
          In<float, 2> Gw, In<float, 1> Gb, In<float, 3> Hw, In<float, 2> Hb, In<float, 2> Ow, In<float, 1> Ob,
          In<double, 1> box, In<bool, 2> mask, bool check, Out<float, 2> q_out, Out<float, 2> p_out,
          Out<int64_t, 2> fail) {
    const int64_t B = x0.shape(0), P = spw.shape(0), k = endb.shape(3), n_max = Bq.shape(2), W = pin.shape(1);
    const int64_t m = ff.shape(1), npar = pin.shape(2), width = Ow.shape(0), layers = Hw.shape(0);
    const int64_t g = mask.shape(0);
    const std::string f(fn);
    need(n_samples >= 0, f + ": n_samples must be >= 0");
    shape(fn, "x0", x0, {B, 2});
    shape(fn, "n_lo", n_lo, {P});
    shape(fn, "vidx", vidx, {B});
    need(B == 0 || (P >= 1 && W >= 1), f + ": needs at least one window basis and one window of inputs per voice");
    shape(fn, "Bq", Bq, {P, k + 3, n_max});
    shape(fn, "Bp", Bp, {P, k + 3, n_max});
    shape(fn, "endb", endb, {P, 2, 2, k});
    shape(fn, "endlin", endlin, {P, 2, 6});
    shape(fn, "center", center, {B, W, 2});
    shape(fn, "halfrange", halfrange, {B, W, 2});
    shape(fn, "ff", ff, {2 + npar, m});
    shape(fn, "pin", pin, {B, W, npar});
    shape(fn, "gain", gain, {B, W});
    shape(fn, "Gw", Gw, {2 * m, 3 * width});
    shape(fn, "Gb", Gb, {3 * width});
    shape(fn, "Hw", Hw, {layers, width, width});
    shape(fn, "Hb", Hb, {layers, width});
    shape(fn, "Ow", Ow, {width, 2 * k});
    shape(fn, "Ob", Ob, {2 * k});
    shape(fn, "box", box, {4});
    need(g >= 1 && static_cast<int64_t>(mask.shape(1)) == g, f + ": mask must be a non-empty square grid");
    need(static_cast<int64_t>(q_out.shape(0)) == B && static_cast<int64_t>(q_out.shape(1)) >= n_samples,
         f + ": q_out must have shape (B, >= n_samples)");
    shape(fn, "p_out", p_out, {B, static_cast<int64_t>(q_out.shape(1))});
    shape(fn, "fail", fail, {B, 2});
    for (int64_t i = 0; i < P; ++i) {  // every window holds floor(spw) or ceil(spw) samples, within the basis
        const double s = spw(i);
        need(std::isfinite(s) && s >= 1.0 && s < 1e12, f + ": spw must be finite and >= 1 (samples per window)");
        need(n_lo(i) == static_cast<int64_t>(std::floor(s)) && static_cast<int64_t>(std::ceil(s)) <= n_max,
             f + ": n_lo must be floor(spw) and the bases must hold ceil(spw) samples");
    }
    for (int64_t b = 0; b < B; ++b) need(vidx(b) >= 0 && vidx(b) < P, f + ": vidx must index the bases");
    bowsynth::Rollout r{B, n_samples, P, k, n_max, W, npar, m, width, layers, g,
                        x0.data(), spw.data(), n_lo.data(), vidx.data(), Bq.data(), Bp.data(), endb.data(),
                        endlin.data(), center.data(), halfrange.data(), ff.data(), pin.data(), gain.data(),
                        Gw.data(), Gb.data(), Hw.data(), Hb.data(), Ow.data(), Ob.data(), box.data(), mask.data(),
                        check, q_out.data(), p_out.data(), static_cast<int64_t>(q_out.shape(1)), fail.data()};
    nb::gil_scoped_release unlocked;
    kernel(r);
}

#define ROLL_ARGS                                                                                                   \
    "x0"_a.noconvert(), "n_samples"_a, "spw"_a.noconvert(), "n_lo"_a.noconvert(), "vidx"_a.noconvert(),           \
        "Bq"_a.noconvert(), "Bp"_a.noconvert(), "endb"_a.noconvert(), "endlin"_a.noconvert(),                      \
        "center"_a.noconvert(), "halfrange"_a.noconvert(), "ff"_a.noconvert(), "pin"_a.noconvert(),                \
        "gain"_a.noconvert(), "Gw"_a.noconvert(), "Gb"_a.noconvert(), "Hw"_a.noconvert(), "Hb"_a.noconvert(),      \
        "Ow"_a.noconvert(), "Ob"_a.noconvert(), "box"_a.noconvert(), "mask"_a.noconvert(), "check"_a,             \
        "q_out"_a.noconvert(), "p_out"_a.noconvert(), "fail"_a.noconvert()

}  // namespace

NB_MODULE(_core, mod) {
    mod.doc() = "bowsynth's compiled core: the FDM step and the operator's rollout loops (see bowsynth/core.py)";
    mod.attr("ABI") = bowsynth::ABI;
    mod.attr("DIGEST") = BOWSYNTH_CORE_DIGEST;
    mod.attr("FAIL_NONFINITE") = bowsynth::FAIL_NONFINITE;
    mod.attr("FAIL_DOMAIN") = bowsynth::FAIL_DOMAIN;
    mod.def("fdm_run", &fdm_run, "u_prev"_a, "u_cur"_a, "eta"_a, "n0"_a, "n_out"_a, "stride"_a, "k"_a,
            "w2_t"_a.noconvert(), "w2_v"_a.noconvert(), "fb_t"_a.noconvert(), "fb_v"_a.noconvert(),
            "vb_t"_a.noconvert(), "vb_v"_a.noconvert(), "a"_a, "tol"_a, "maxit"_a, "u_out"_a.noconvert(),
            "eta_out"_a.noconvert(),
            "Steps n0, n0 + 1, ... of the FDM; w^2, F_B and v_B follow their breakpoints (t, v) per step. Writes u and "
            "eta at every stride-th step into u_out, eta_out; returns (u_prev, u_cur, eta) to continue from.");
    mod.def(
        "roll_voices",
        [](In<double, 2> x0, int64_t n, In<double, 1> spw, In<int64_t, 1> n_lo, In<int64_t, 1> vidx, In<float, 3> Bq,
           In<float, 3> Bp, In<double, 4> endb, In<double, 3> endlin, In<double, 3> c, In<double, 3> hr,
           In<double, 2> ff, In<double, 3> pin, In<double, 2> gain, In<float, 2> Gw, In<float, 1> Gb, In<float, 3> Hw,
           In<float, 2> Hb, In<float, 2> Ow, In<float, 1> Ob, In<double, 1> box, In<bool, 2> mask, bool check,
           Out<float, 2> q, Out<float, 2> p, Out<int64_t, 2> fail) {
            roll<bowsynth::roll_voices>("roll_voices", x0, n, spw, n_lo, vidx, Bq, Bp, endb, endlin, c, hr, ff, pin,
                                        gain, Gw, Gb, Hw, Hb, Ow, Ob, box, mask, check, q, p, fail);
        },
        ROLL_ARGS, "The rollout, one voice after another (matrix-vector products).");
    mod.def(
        "roll_batch",
        [](In<double, 2> x0, int64_t n, In<double, 1> spw, In<int64_t, 1> n_lo, In<int64_t, 1> vidx, In<float, 3> Bq,
           In<float, 3> Bp, In<double, 4> endb, In<double, 3> endlin, In<double, 3> c, In<double, 3> hr,
           In<double, 2> ff, In<double, 3> pin, In<double, 2> gain, In<float, 2> Gw, In<float, 1> Gb, In<float, 3> Hw,
           In<float, 2> Hb, In<float, 2> Ow, In<float, 1> Ob, In<double, 1> box, In<bool, 2> mask, bool check,
           Out<float, 2> q, Out<float, 2> p, Out<int64_t, 2> fail) {
            roll<bowsynth::roll_batch>("roll_batch", x0, n, spw, n_lo, vidx, Bq, Bp, endb, endlin, c, hr, ff, pin,
                                       gain, Gw, Gb, Hw, Hb, Ow, Ob, box, mask, check, q, p, fail);
        },
        ROLL_ARGS, "The rollout, every voice one window at a time (matrix-matrix products over the voices).");
    // the rollout's own approximations and window rule, exposed for the tests
    mod.def("_tanh32", &bowsynth::tanh32_of, "x"_a);
    mod.def("_cos_sin", [](double z) {
        double c, s;
        bowsynth::cos_sin_of(z, c, s);
        return std::make_tuple(c, s);
    }, "z"_a);
    mod.def("_window_end", &bowsynth::window_end_of, "w"_a, "spw"_a);
}
