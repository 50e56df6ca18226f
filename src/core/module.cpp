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
#include <vector>

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

// The branch network's weights and the domain's box and mask, as the offline loops and the live Voices take them:
// checked once here for both (m, width and layers are read from ff, Ow and Hw; the rest must agree with them)
void check_net(const char* fn, int64_t npar, int64_t k, const In<double, 2>& ff, const In<float, 2>& Gw,
               const In<float, 1>& Gb, const In<float, 3>& Hw, const In<float, 2>& Hb, const In<float, 2>& Ow,
               const In<float, 1>& Ob, const In<double, 1>& box, const In<bool, 2>& mask) {
    const int64_t m = ff.shape(1), width = Ow.shape(0), layers = Hw.shape(0), g = mask.shape(0);
    shape(fn, "ff", ff, {2 + npar, m});
    shape(fn, "Gw", Gw, {2 * m, 3 * width});
    shape(fn, "Gb", Gb, {3 * width});
    shape(fn, "Hw", Hw, {layers, width, width});
    shape(fn, "Hb", Hb, {layers, width});
    shape(fn, "Ow", Ow, {width, 2 * k});
    shape(fn, "Ob", Ob, {2 * k});
    shape(fn, "box", box, {4});
    need(g >= 1 && static_cast<int64_t>(mask.shape(1)) == g,
         std::string(fn) + ": mask must be a non-empty square grid");
}

template <Roll kernel>
void roll(const char* fn, In<double, 2> x0, int64_t n_samples, In<double, 1> spw, In<int64_t, 1> n_lo,
          In<int64_t, 1> vidx, In<float, 3> Bq, In<float, 3> Bp, In<double, 4> endb, In<double, 3> endlin,
          In<double, 3> center, In<double, 3> halfrange, In<double, 2> ff, In<double, 3> pin, In<double, 2> gain,
          In<float, 2> Gw, In<float, 1> Gb, In<float, 3> Hw, In<float, 2> Hb, In<float, 2> Ow, In<float, 1> Ob,
          In<double, 1> box, In<bool, 2> mask, bool check, Out<float, 2> q_out, Out<float, 2> p_out,
          Out<int64_t, 2> fail, In<int64_t, 1> rows) {
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
    shape(fn, "pin", pin, {B, W, npar});
    shape(fn, "gain", gain, {B, W});
    check_net(fn, npar, k, ff, Gw, Gb, Hw, Hb, Ow, Ob, box, mask);
    const int64_t n_rows = q_out.shape(0);
    need(static_cast<int64_t>(q_out.shape(1)) >= n_samples, f + ": q_out must have shape (rows, >= n_samples)");
    shape(fn, "p_out", p_out, {n_rows, static_cast<int64_t>(q_out.shape(1))});
    shape(fn, "fail", fail, {n_rows, 2});
    shape(fn, "rows", rows, {B});
    for (int64_t b = 0; b < B; ++b) need(rows(b) >= 0 && rows(b) < n_rows, f + ": rows must index q_out's rows");
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
                        check, q_out.data(), p_out.data(), static_cast<int64_t>(q_out.shape(1)), fail.data(),
                        rows.data()};
    nb::gil_scoped_release unlocked;
    kernel(r);
}

#define ROLL_ARGS                                                                                                   \
    "x0"_a.noconvert(), "n_samples"_a, "spw"_a.noconvert(), "n_lo"_a.noconvert(), "vidx"_a.noconvert(),           \
        "Bq"_a.noconvert(), "Bp"_a.noconvert(), "endb"_a.noconvert(), "endlin"_a.noconvert(),                      \
        "center"_a.noconvert(), "halfrange"_a.noconvert(), "ff"_a.noconvert(), "pin"_a.noconvert(),                \
        "gain"_a.noconvert(), "Gw"_a.noconvert(), "Gb"_a.noconvert(), "Hw"_a.noconvert(), "Hb"_a.noconvert(),      \
        "Ow"_a.noconvert(), "Ob"_a.noconvert(), "box"_a.noconvert(), "mask"_a.noconvert(), "check"_a,             \
        "q_out"_a.noconvert(), "p_out"_a.noconvert(), "fail"_a.noconvert(), "rows"_a.noconvert()


// ---- the block-by-block voices (voices.cpp) ----

template <typename T>
const char* dtype_name() {
    return std::is_same_v<T, float> ? "float32" : std::is_same_v<T, double> ? "float64"
                                                : std::is_same_v<T, bool>   ? "bool"
                                                                            : "int64";
}

// item i of a tuple, as an array of exactly this dtype and rank, C-contiguous (never converted: the kernel writes
// into the bank's own arrays)
template <typename T, size_t N>
nb::ndarray<T, nb::ndim<N>, nb::c_contig, nb::device::cpu> item(nb::handle tup, size_t i, const char* name) {
    nb::ndarray<T, nb::ndim<N>, nb::c_contig, nb::device::cpu> a;
    if (!nb::try_cast(tup[i], a, false))
        throw nb::type_error((std::string("Voices: ") + name + " must be a C-contiguous" +
                              (std::is_const_v<T> ? " " : ", writable ") + dtype_name<std::remove_const_t<T>>() +
                              " array of rank " + std::to_string(N))
                                 .c_str());
    return a;
}

size_t count(nb::handle tup, size_t n, const char* name) {
    if (!nb::isinstance<nb::tuple>(tup) || nb::len(tup) != n)
        throw nb::type_error((std::string("Voices: ") + name + " must be a tuple of " + std::to_string(n)).c_str());
    return n;
}

// The slots' arrays (bank.VoiceBank), checked once here and referenced from then on: Python writes a slot's note
// into them between calls, the kernels read and write them with the GIL released.
struct VoicesPy {
    bowsynth::Voices V{};
    nb::object keep;  // the tuples, so that the arrays outlive this object
    std::vector<float> s, panels;
    std::vector<double> zd, wts;
    std::vector<int64_t> idx;

    VoicesPy(nb::tuple slots, nb::tuple ops, nb::tuple net, nb::tuple tb, nb::tuple fdm, nb::tuple pit, double tol,
             int64_t maxit) {
        const char* fn = "Voices";
        count(slots, 4, "slots");
        count(ops, 19, "ops");
        count(net, 9, "net");
        count(tb, 9, "tb");
        count(fdm, 9, "fdm");
        count(pit, 9, "pit");
        keep = nb::make_tuple(slots, ops, net, tb, fdm, pit);
        auto mode = item<int64_t, 1>(slots, 0, "mode"), pos = item<int64_t, 1>(slots, 1, "pos"),
             end = item<int64_t, 1>(slots, 2, "end"), why = item<int64_t, 1>(slots, 3, "why");
        const int64_t nv = mode.shape(0);
        shape(fn, "pos", pos, {nv});
        shape(fn, "end", end, {nv});
        shape(fn, "why", why, {nv});
        auto x = item<double, 2>(ops, 0, "x");
        auto spw = item<double, 1>(ops, 1, "spw");
        auto n_lo = item<int64_t, 1>(ops, 2, "n_lo");
        auto Bq = item<float, 3>(ops, 3, "Bq"), Bp = item<float, 3>(ops, 4, "Bp");
        auto endb = item<double, 4>(ops, 5, "endb");
        auto endlin = item<double, 3>(ops, 6, "endlin");
        auto center = item<double, 2>(ops, 7, "center"), half = item<double, 2>(ops, 8, "halfrange");
        auto pin = item<double, 2>(ops, 9, "pin");
        auto gain = item<double, 1>(ops, 10, "gain");
        auto win = item<int64_t, 1>(ops, 11, "win"), wstart = item<int64_t, 1>(ops, 12, "wstart"),
             wlen = item<int64_t, 1>(ops, 13, "wlen");
        auto qbuf = item<float, 2>(ops, 14, "qbuf"), pbuf = item<float, 2>(ops, 15, "pbuf");
        auto op_end = item<int64_t, 1>(ops, 16, "op_end");
        auto rest = item<double, 2>(ops, 17, "rest");
        auto orig = item<int64_t, 1>(ops, 18, "orig");
        const int64_t k = endb.shape(3), n_max = Bq.shape(2), npar = pin.shape(1);
        need(n_max >= 3, "Voices: a slot's window buffer must hold at least 3 samples");
        shape(fn, "x", x, {nv, 2});
        for (auto* a : {&spw, &gain}) shape(fn, "spw / gain", *a, {nv});
        for (auto* a : {&n_lo, &win, &wstart, &wlen, &op_end, &orig})
            shape(fn, "n_lo / win / wstart / wlen / op_end / orig", *a, {nv});
        shape(fn, "rest", rest, {nv, bowsynth::REST_COLS});
        shape(fn, "Bq", Bq, {nv, k + 3, n_max});
        shape(fn, "Bp", Bp, {nv, k + 3, n_max});
        shape(fn, "endb", endb, {nv, 2, 2, k});
        shape(fn, "endlin", endlin, {nv, 2, 6});
        shape(fn, "center", center, {nv, 2});
        shape(fn, "halfrange", half, {nv, 2});
        shape(fn, "qbuf", qbuf, {nv, n_max});
        shape(fn, "pbuf", pbuf, {nv, n_max});
        auto ff = item<const double, 2>(net, 0, "ff");
        auto Gw = item<const float, 2>(net, 1, "Gw");
        auto Gb = item<const float, 1>(net, 2, "Gb");
        auto Hw = item<const float, 3>(net, 3, "Hw");
        auto Hb = item<const float, 2>(net, 4, "Hb");
        auto Ow = item<const float, 2>(net, 5, "Ow");
        auto Ob = item<const float, 1>(net, 6, "Ob");
        auto box = item<const double, 1>(net, 7, "box");
        auto mask = item<const bool, 2>(net, 8, "mask");
        check_net(fn, npar, k, ff, Gw, Gb, Hw, Hb, Ow, Ob, box, mask);
        const int64_t m = ff.shape(1), width = Ow.shape(0), layers = Hw.shape(0), g = mask.shape(0);
        auto grid = item<const double, 3>(tb, 0, "grid");
        const int64_t G = grid.shape(2);
        shape(fn, "grid", grid, {2, k, G});
        need(G >= 4, "Voices: the trunk grid needs at least 4 points");
        auto corr = item<const double, 1>(tb, 2, "corr_scale"), bias = item<const double, 1>(tb, 3, "bias");
        shape(fn, "corr_scale", corr, {2});
        shape(fn, "bias", bias, {2});
        const double h_grid = nb::cast<double>(tb[1]), window = nb::cast<double>(tb[4]);
        const int64_t lin_kind = nb::cast<int64_t>(tb[5]);
        const double lin_d = nb::cast<double>(tb[6]), lin_qs = nb::cast<double>(tb[7]), sr = nb::cast<double>(tb[8]);
        need(std::isfinite(h_grid) && h_grid > 0 && std::isfinite(window) && window > 0 && std::isfinite(sr) && sr > 0,
             "Voices: the grid spacing, the window and the sample rate must be positive numbers");
        need(lin_kind >= 0 && lin_kind <= 2, "Voices: lin_kind must be 0, 1 or 2");
        auto fst = item<double, 2>(fdm, 0, "fst");
        auto fint = item<int64_t, 2>(fdm, 1, "fint");
        auto vb_t = item<double, 2>(fdm, 2, "vb_t"), vb_v = item<double, 2>(fdm, 3, "vb_v");
        auto nvb = item<int64_t, 1>(fdm, 4, "nvb");
        auto fb_t = item<double, 2>(fdm, 5, "fb_t"), fb_v = item<double, 2>(fdm, 6, "fb_v");
        auto su = item<double, 2>(fdm, 7, "su"), se = item<double, 2>(fdm, 8, "se");
        const int64_t bl = su.shape(1);
        shape(fn, "fst", fst, {nv, 7});
        shape(fn, "fint", fint, {nv, 2});
        shape(fn, "vb_t", vb_t, {nv, 3});
        shape(fn, "vb_v", vb_v, {nv, 3});
        shape(fn, "nvb", nvb, {nv});
        shape(fn, "fb_t", fb_t, {nv, 2});
        shape(fn, "fb_v", fb_v, {nv, 2});
        shape(fn, "su", su, {nv, bl});
        shape(fn, "se", se, {nv, bl});
        need(bl >= 1, "Voices: the FDM's scratch rows must hold a block");
        auto pm = item<int64_t, 1>(pit, 0, "pm");
        auto pp = item<const double, 2>(pit, 1, "pp");
        auto pt = item<const double, 2>(pit, 2, "pt"), pv = item<const double, 2>(pit, 3, "pv");
        auto npt = item<const int64_t, 1>(pit, 4, "npt");
        auto wfrac = item<double, 1>(pit, 5, "wfrac"), bdtau = item<double, 1>(pit, 6, "bdtau");
        auto wt = item<double, 2>(pit, 7, "wt"), wv = item<double, 2>(pit, 8, "wv");
        const int64_t cp = pt.shape(1);
        shape(fn, "pm", pm, {nv});
        shape(fn, "pp", pp, {nv, bowsynth::P_COLS});
        shape(fn, "pt", pt, {nv, cp});
        shape(fn, "pv", pv, {nv, cp});
        shape(fn, "npt", npt, {nv});
        shape(fn, "wfrac", wfrac, {nv});
        shape(fn, "bdtau", bdtau, {nv});
        shape(fn, "wt", wt, {nv, 2});
        shape(fn, "wv", wv, {nv, 2});
        need(cp >= 1, "Voices: a pitch curve needs room for a breakpoint");
        need(maxit >= 1 && tol >= 0, "Voices: needs tol >= 0 and maxit >= 1");
        bowsynth::Net N{m, npar, width, layers, k, g, ff.data(), Gw.data(), Gb.data(), Hw.data(), Hb.data(),
                        Ow.data(), Ob.data(), box.data(), mask.data()};
        panels.resize(bowsynth::panel_floats(N));  // once: the blocks allocate nothing
        bowsynth::pack_net(N, panels.data());
        s.resize(bowsynth::live_scratch(N));
        zd.resize(std::max<int64_t>(m, 1));
        idx.resize(n_max + 1);
        wts.resize(4 * (n_max + 1));
        V = bowsynth::Voices{nv, k, n_max, npar, G, bl, cp, mode.data(), pos.data(), end.data(), why.data(),
                             x.data(), spw.data(), n_lo.data(), Bq.data(), Bp.data(), endb.data(), endlin.data(),
                             center.data(), half.data(), pin.data(), gain.data(), win.data(), wstart.data(),
                             wlen.data(), qbuf.data(), pbuf.data(), op_end.data(), rest.data(), orig.data(), N,
                             grid.data(), h_grid,
                             corr.data(), bias.data(), window, lin_kind, lin_d, lin_qs, sr, fst.data(), fint.data(),
                             vb_t.data(), vb_v.data(), nvb.data(), fb_t.data(), fb_v.data(), su.data(), se.data(),
                             pm.data(), pp.data(), pt.data(), pv.data(), npt.data(), wfrac.data(), bdtau.data(),
                             wt.data(), wv.data(), tol, maxit, s.data(), zd.data(), idx.data(), wts.data()};
    }

    void slot(const char* fn, int64_t v) const {
        need(v >= 0 && v < V.nv, std::string(fn) + ": slot " + std::to_string(v) + " out of range");
    }

    // What Python wrote into a slot between calls, checked before the kernel trusts it (what the kernel writes
    // itself stays within these bounds)
    void check_slot(const char* fn, int64_t v) const {
        const std::string f = std::string(fn) + ": slot " + std::to_string(v) + " ";
        const int64_t md = V.mode[v];
        need(md == bowsynth::FREE || md == bowsynth::OPERATOR || md == bowsynth::FDM || md == bowsynth::REST,
             f + "has no valid mode");
        if (md == bowsynth::FREE) return;
        const int64_t pm = V.pm[v];
        need(pm == bowsynth::HELD || pm == bowsynth::CURVE || pm == bowsynth::LIVE, f + "has no valid pitch mode");
        need(pm != bowsynth::CURVE || (V.npt[v] >= 1 && V.npt[v] <= V.cp), f + "has a pitch curve of no points");
        need(V.pos[v] >= 0, f + "has a negative position");
        need(V.nvb[v] >= 1 && V.nvb[v] <= 3, f + "needs 1 to 3 bow breakpoints");
        need(V.fint[2 * v] >= 0 && V.fint[2 * v + 1] >= 1, f + "needs an FDM step count >= 0 and stride >= 1");
        need(std::isfinite(V.fst[7 * v + 3]) && V.fst[7 * v + 3] > 0, f + "needs a positive FDM step");
        if (md != bowsynth::OPERATOR && md != bowsynth::REST) return;
        if (md == bowsynth::REST) {  // the rest flow, then the operator from where it ends
            const double* R = V.rest + bowsynth::REST_COLS * v;
            need(std::isfinite(R[bowsynth::R_RADIUS]) && R[bowsynth::R_RADIUS] >= 0 &&
                     std::isfinite(R[bowsynth::R_D]) && std::isfinite(R[6]),
                 f + "needs a rest flow of radius >= 0, a finite d and a finite rest point");
            need(V.pos[v] >= V.orig[v] && V.orig[v] >= 0, f + "has its partition's start after its position");
        }
        const double sw = V.spw[v];
        need(std::isfinite(sw) && sw >= 1.0 && std::ceil(sw) + 1 <= V.n_max && V.n_lo[v] == std::floor(sw),
             f + "needs 1 <= spw, ceil(spw) + 1 <= the buffer, n_lo = floor(spw)");
        need(V.wlen[v] >= 0 && V.wlen[v] <= V.n_max && V.wstart[v] >= 0 && V.wstart[v] <= V.pos[v] &&
                 V.win[v] >= -1,
             f + "has a window outside its buffer");
        const int64_t ws = V.wstart[v], oe = V.op_end[v];
        need(oe < 0 || (oe >= ws && oe < ws + std::max<int64_t>(V.wlen[v], 1)),
             f + "hands over outside its window");
    }

    void render(Out<double, 1> out, Out<double, 1> outp, int64_t off, int64_t m, double amp) {
        const int64_t n = out.shape(0);
        need(off >= 0 && m >= 0 && off + m <= n, "render: needs 0 <= off, 0 <= m, off + m <= len(out)");
        need(outp.shape(0) == 0 || static_cast<int64_t>(outp.shape(0)) == n,
             "render: outp must be empty or as long as out");
        for (int64_t v = 0; v < V.nv; ++v) check_slot("render", v);
        nb::gil_scoped_release unlocked;
        bowsynth::voices_render(V, out.data() + off, outp.shape(0) ? outp.data() + off : nullptr, m, amp);
    }
    void advance_to(int64_t v, int64_t target) {
        slot("advance_to", v);
        check_slot("advance_to", v);
        need(V.mode[v] == bowsynth::OPERATOR, "advance_to: the slot is not an operator's");
        nb::gil_scoped_release unlocked;
        bowsynth::voices_advance_to(V, v, target);
    }
    void to_fdm(int64_t v, double q0, double p0, int64_t at) {
        slot("to_fdm", v);
        need(V.nvb[v] >= 1 && V.nvb[v] <= 3, "to_fdm: the slot needs 1 to 3 bow breakpoints");
        need(V.pm[v] != bowsynth::CURVE || (V.npt[v] >= 1 && V.npt[v] <= V.cp), "to_fdm: a pitch curve of no points");
        bowsynth::voices_to_fdm(V, v, q0, p0, at);
    }
    void trunk_basis(int64_t v, double dtau, int64_t n_lo, int64_t n_hi) {
        slot("trunk_basis", v);
        need(std::isfinite(dtau) && dtau > 0 && n_lo >= 1 && n_lo <= n_hi && n_hi + 1 <= V.n_max,
             "trunk_basis: needs dtau > 0 and 1 <= n_lo <= n_hi, n_hi + 1 <= the slot's buffer");
        nb::gil_scoped_release unlocked;
        bowsynth::voices_trunk_basis(V, v, dtau, n_lo, n_hi);
    }
};

}  // namespace

NB_MODULE(_core, mod) {
    mod.doc() = "bowsynth's compiled core: the FDM step, the operator's rollout loops and the live voice loop "
                "(see bowsynth/engines/core)";
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
           Out<float, 2> q, Out<float, 2> p, Out<int64_t, 2> fail, In<int64_t, 1> rows) {
            roll<bowsynth::roll_voices>("roll_voices", x0, n, spw, n_lo, vidx, Bq, Bp, endb, endlin, c, hr, ff, pin,
                                        gain, Gw, Gb, Hw, Hb, Ow, Ob, box, mask, check, q, p, fail, rows);
        },
        ROLL_ARGS, "The rollout, one voice after another (matrix-vector products).");
    mod.def(
        "roll_batch",
        [](In<double, 2> x0, int64_t n, In<double, 1> spw, In<int64_t, 1> n_lo, In<int64_t, 1> vidx, In<float, 3> Bq,
           In<float, 3> Bp, In<double, 4> endb, In<double, 3> endlin, In<double, 3> c, In<double, 3> hr,
           In<double, 2> ff, In<double, 3> pin, In<double, 2> gain, In<float, 2> Gw, In<float, 1> Gb, In<float, 3> Hw,
           In<float, 2> Hb, In<float, 2> Ow, In<float, 1> Ob, In<double, 1> box, In<bool, 2> mask, bool check,
           Out<float, 2> q, Out<float, 2> p, Out<int64_t, 2> fail, In<int64_t, 1> rows) {
            roll<bowsynth::roll_batch>("roll_batch", x0, n, spw, n_lo, vidx, Bq, Bp, endb, endlin, c, hr, ff, pin,
                                       gain, Gw, Gb, Hw, Hb, Ow, Ob, box, mask, check, q, p, fail, rows);
        },
        ROLL_ARGS, "The rollout, every voice one window at a time (matrix-matrix products over the voices).");
    nb::class_<VoicesPy>(mod, "Voices",
                         "Slots that play block by block, over the arrays of engines.operator.bank.VoiceBank "
                         "(referenced, not copied).")
        .def(nb::init<nb::tuple, nb::tuple, nb::tuple, nb::tuple, nb::tuple, nb::tuple, double, int64_t>(),
             "slots"_a, "ops"_a, "net"_a, "tb"_a, "fdm"_a, "pit"_a, "tol"_a, "maxit"_a)
        .def("render", &VoicesPy::render, "out"_a.noconvert(), "outp"_a.noconvert(), "off"_a, "m"_a, "amp"_a,
             "Add m samples of every sounding slot, times amp, to out[off:off + m] (and their p to outp, unless "
             "empty).")
        .def("advance_to", &VoicesPy::advance_to, "slot"_a, "target"_a,
             "Compute an operator slot's windows until its buffer holds the note's sample target.")
        .def("to_fdm", &VoicesPy::to_fdm, "slot"_a, "q0"_a, "p0"_a, "at"_a,
             "The slot goes on with the FDM from the state (q0, p0) at the note's sample at.")
        .def("trunk_basis", &VoicesPy::trunk_basis, "slot"_a, "dtau"_a, "n_lo"_a, "n_hi"_a,
             "The slot's window basis at sample spacing dtau, for windows of n_lo and n_hi samples.");
    mod.def("pick_slot", [](In<int64_t, 1> mode, In<int64_t, 1> end, In<int64_t, 1> pos, In<int64_t, 1> start) {
        const int64_t nv = mode.shape(0);
        need(nv >= 1, "pick_slot: needs at least one slot");
        for (auto* a : {&end, &pos, &start}) shape("pick_slot", "end / pos / start", *a, {nv});
        return bowsynth::pick_slot(mode.data(), end.data(), pos.data(), start.data(), nv);
    }, "mode"_a.noconvert(), "end"_a.noconvert(), "pos"_a.noconvert(), "start"_a.noconvert(),
       "A free slot; else the one to steal: the releasing voice nearest its end, else the oldest.");
    mod.def("dc_block", [](In<double, 1> x, int64_t n, double r, Out<double, 1> state, Out<float, 1> y) {
        need(n >= 0 && n <= static_cast<int64_t>(x.shape(0)) && n <= static_cast<int64_t>(y.shape(0)),
             "dc_block: x and y must hold n values");
        shape("dc_block", "state", state, {2});
        bowsynth::dc_block(x.data(), n, r, state.data(), y.data());
    }, "x"_a.noconvert(), "n"_a, "r"_a, "state"_a.noconvert(), "y"_a.noconvert(),
       "y[:n] = the causal DC blocker y[i] = x[i] - x[i - 1] + r y[i - 1] of x[:n], its memory in state.");
    mod.def("highpass_zero_phase", [](Out<double, 1> x, double K) {
        need(std::isfinite(K) && K > 0, "highpass_zero_phase: K = tan(pi f_c / f_s) must be a positive number");
        double* xs = x.data();
        const int64_t n = x.shape(0);
        nb::gil_scoped_release nogil;
        bowsynth::highpass_zero_phase(xs, n, K);
    }, "x"_a.noconvert(), "K"_a,
       "x high-passed in place, forward then backward, by a 2nd-order Butterworth at K = tan(pi f_c / f_s).");
    mod.def("polyphase", [](In<double, 2> x, In<double, 2> w, int64_t up, int64_t down, Out<float, 2> y) {
        // y[r, j] = sum_k w[(j down) mod up, k] x[r, (j down) div up + k]: a rational resampler whose filter is
        // given per phase (engines.operator.grid)
        const int64_t rows = x.shape(0), n_in = x.shape(1), n_out = y.shape(1), K = w.shape(1);
        need(up >= 1 && down >= 1, "polyphase: up and down must be >= 1");
        shape("polyphase", "w", w, {up, K});
        shape("polyphase", "y", y, {rows, n_out});
        need(n_out == 0 || ((n_out - 1) * down) / up + K <= n_in,
             "polyphase: x is too short for n_out samples (it needs (n_out - 1) down / up + K)");
        const double* xs = x.data();
        const double* ws = w.data();
        float* ys = y.data();
        nb::gil_scoped_release nogil;
        bowsynth::polyphase(xs, rows, n_in, ws, up, K, down, ys, n_out);
    }, "x"_a.noconvert(), "w"_a.noconvert(), "up"_a, "down"_a, "y"_a.noconvert(),
       "y[r, j] = sum_k w[(j down) mod up, k] x[r, (j down) div up + k]: resampling by up / down, the filter per "
       "phase.");
    mod.def("resample_rows", [](In<float, 2> x, In<double, 2> w, int64_t k0, int64_t up, int64_t down,
                                Out<float, 2> y) {
        const int64_t rows = x.shape(0), n_in = x.shape(1), n_out = y.shape(1), K = w.shape(1);
        need(up >= 1 && down >= 1, "resample_rows: up and down must be >= 1");
        need(k0 >= 0 && K == 2 * k0 + 1, "resample_rows: w must have 2 k0 + 1 taps");
        need(n_in >= k0 + 2, "resample_rows: x needs at least k0 + 2 samples a row");
        shape("resample_rows", "w", w, {up, K});
        shape("resample_rows", "y", y, {rows, n_out});
        need(n_out == 0 || ((n_out - 1) * down) / up + K <= n_in + 2 * k0,
             "resample_rows: x is too short for n_out samples");
        const float* xs = x.data();
        const double* ws = w.data();
        float* ys = y.data();
        // in place only as the loop can do it: y the start of x's one row, the ratio at most 1 (an output reads
        // no input before its own index, less k0); any other overlap would read samples already overwritten
        const bool overlap = ys < xs + rows * n_in && xs < ys + rows * n_out;
        need(!overlap || (ys == xs && rows == 1 && down >= up),
             "resample_rows: y may overlap x only as x's own single row (y = x[:, :n_out]) with down >= up");
        nb::gil_scoped_release nogil;
        bowsynth::resample_rows(xs, rows, n_in, ws, up, K, k0, down, ys, n_out);
    }, "x"_a.noconvert(), "w"_a.noconvert(), "k0"_a, "up"_a, "down"_a, "y"_a.noconvert(),
       "Rows of float32 grid samples held at their last finite sample, continued oddly by k0 samples at both ends and "
       "resampled by up / down (engines.operator.grid.to_output); in place where y = x[:, :n_out] of one row.");
    mod.def("rest_coefficients", [](In<double, 1> d, In<double, 1> qs, In<double, 1> dtau, Out<double, 2> c) {
        const int64_t n = d.shape(0);
        shape("rest_coefficients", "qs", qs, {n});
        shape("rest_coefficients", "dtau", dtau, {n});
        need(static_cast<int64_t>(c.shape(0)) == n && c.shape(1) >= 7, "rest_coefficients: c must be (n, >= 7)");
        for (int64_t i = 0; i < n; ++i)
            need(std::isfinite(d.data()[i]), "rest_coefficients: needs a finite d");
        const int64_t w = c.shape(1);
        for (int64_t i = 0; i < n; ++i)
            bowsynth::rest_coefficients(d.data()[i], qs.data()[i], dtau.data()[i], c.data() + w * i);
    }, "d"_a.noconvert(), "qs"_a.noconvert(), "dtau"_a.noconvert(), "c"_a.noconvert(),
       "c[i, :7] = M (4), k (2) and q_s of one step dtau[i] of the flow linearised at the bow's rest point (d[i], "
       "qs[i]); the columns after the 7th are left as they are.");
    mod.def("rest_run", [](double q, double p, In<double, 2> c, int64_t n, Out<double, 1> oq, Out<double, 1> op) {
        const int64_t m = c.shape(0);
        need(c.shape(1) == bowsynth::REST_ROW && (m == 1 || m >= n), "rest_run: c must be (1, 8) or (>= n, 8)");
        need(n >= 0 && static_cast<int64_t>(oq.shape(0)) >= n && static_cast<int64_t>(op.shape(0)) >= n,
             "rest_run: oq and op must hold n samples");
        const int64_t h = bowsynth::rest_run(q, p, c.data(), m == 1 ? 0 : bowsynth::REST_ROW, n, oq.data(), op.data());
        return std::make_tuple(h, q, p);
    }, "q"_a, "p"_a, "c"_a.noconvert(), "n"_a, "oq"_a.noconvert(), "op"_a.noconvert(),
       "The rest flow from (q, p) while within the radius c[:, 7] of the rest point c[:, 6]: its samples into oq, "
       "op (row i for sample i, or row 0 throughout); returns (samples written, q, p at the next).");
    mod.def("ramp", &bowsynth::voices_ramp, "a"_a, "b"_a, "t0"_a, "length"_a, "s"_a,
            "a until t0, then linear to b over length, then b (a live pitch control's ramp).");
    for (auto [name, value] : {std::pair{"FREE", bowsynth::FREE}, {"OPERATOR", bowsynth::OPERATOR},
                               {"FDM", bowsynth::FDM}, {"REST", bowsynth::REST}, {"REST_COLS", bowsynth::REST_COLS},
                               {"HELD", bowsynth::HELD}, {"CURVE", bowsynth::CURVE},
                               {"LIVE", bowsynth::LIVE}, {"WHY_OK", bowsynth::WHY_OK},
                               {"WHY_FALLBACK", bowsynth::WHY_FALLBACK}, {"P_COLS", bowsynth::P_COLS}})
        mod.attr(name) = value;
    // the rollout's own approximations and window rule, exposed for the tests
    mod.def("_tanh32", &bowsynth::tanh32_of, "x"_a);
    mod.def("_cos_sin", [](double z) {
        double c, s;
        bowsynth::cos_sin_of(z, c, s);
        return std::make_tuple(c, s);
    }, "z"_a);
    mod.def("_window_end", &bowsynth::window_end_of, "w"_a, "spw"_a);
#ifdef BOWSYNTH_HAVE_V16
    mod.attr("AVX512_BUILT") = true;
#else
    mod.attr("AVX512_BUILT") = false;
#endif
    mod.def("vector_width", [] { return bowsynth::use_v16() ? 16 : 8; },
            "Floats in a matrix product's vector in the rollout loops this process runs: 16 where the CPU runs "
            "AVX-512 and BOWSYNTH_NO_AVX512 is not set, else 8.");
    mod.def("panels", &bowsynth::use_panels,
            "Whether one voice's branch reads its weights in panels (unless BOWSYNTH_NO_PANELS is set): the same "
            "samples, faster.");
}
