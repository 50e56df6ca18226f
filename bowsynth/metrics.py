"""Error metrics, defined once: the paper's NMSE and NCC, plus phase-insensitive pitch and spectrum measures."""

from __future__ import annotations

import math

import numpy as np

from . import physics


def nmse(x, ref) -> float:
    """mean((x - ref)^2) / var(ref), the paper's definition."""
    x, ref = np.asarray(x, float), np.asarray(ref, float)
    v = np.var(ref)
    return float(np.mean((x - ref) ** 2) / v) if v > 0 else float(np.mean((x - ref) ** 2))


def ncc(x, ref) -> float:
    """Pearson correlation in percent."""
    x, ref = np.asarray(x, float), np.asarray(ref, float)
    if np.std(x) == 0 or np.std(ref) == 0:
        return float("nan")
    return float(100.0 * np.corrcoef(x, ref)[0, 1])


# An upward zero crossing counts toward the pitch only where the signal dipped at least this share of the deepest dip
# within a period of it below its mean since the previous crossing (a Schmitt trigger's lower threshold). Why: the slowest heavy bows, just above vb_stop, creep for most of a period with p drifting down to its mean before
# each slip, and there a render's ripple of a few hundredths (a lock's window handovers) crosses the mean two or three
# times a period. Those crossings halved the median period, the filter below then kept them, and a note whose waveform
# lies on the truth's read 1281 cents sharp (stick-halt at 110 Hz, F_B / w 1.6, v_B 0.071: dips 0.003-0.047 against
# the slip's 1.59). A clean note's crossings all dip to its trough: nothing changes there (the audio-rate FDM's ratio
# at 1 kHz, settled to 2e-7 between chunks, did not settle when a chunk's first crossing was judged by its cut dip).
# Within a period, not the whole segment: a note that grows tenfold keeps its quiet crossings (tests/test_listener.py).
CROSS_DIP = 0.25


def median(a) -> float:
    """np.median of the values (NaN where one is NaN or there are none), without the import of numpy.ma that
    np.median's NaN check makes on first use: ~10 ms of a render's process, which measures pitches.

    >>> median([3.0, 1.0, 2.0, 10.0]), median([])
    (2.5, nan)
    """
    s = np.sort(np.asarray(a, float).ravel())
    if len(s) == 0 or np.isnan(s[-1]):
        return float("nan")
    m = len(s) // 2
    return float(s[m]) if len(s) % 2 else float((s[m - 1] + s[m]) / 2)


def f0_estimate(x, sample_rate: float, tail: float = 0.5) -> float:
    """Fundamental from interpolated upward zero crossings of the last `tail` fraction (the steady state)."""
    x = np.asarray(x, float)
    x = x[int(len(x) * (1 - tail)):]
    x = x - x.mean()
    if len(x) < 4 or np.std(x) == 0:
        return float("nan")
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    if len(i) < 3:
        return float("nan")
    # a crossing counts where the signal went CROSS_DIP of the deepest dip within a period on either side below the
    # mean since the previous crossing (the period: between crossings that dip CROSS_DIP of the segment's deepest);
    # only where some crossing after the first did not (a clean note's estimate stays what it was)
    dips = np.minimum.reduceat(x, np.concatenate([[0], i + 1]))[:len(i)]
    deep = dips <= CROSS_DIP * dips.min()
    if not deep[1:].all():
        if deep.sum() >= 2:
            period = median(np.diff(i[deep]))
            lo, hi = np.searchsorted(i, i - period), np.searchsorted(i, i + period, side="right")
            deep = dips <= CROSS_DIP * np.array([dips[a:b].min() for a, b in zip(lo, hi)])
            # the first crossing's dip is cut by the segment's start: it counts where the next counted one follows a
            # period later (give or take a quarter), as on a clean note; else it is a ripple's or a shallow harmonic's
            later = i[1:][deep[1:]]
            deep[0] = bool(len(later)) and abs(later[0] - i[0] - period) < 0.25 * period
        i = i[deep]
        if len(i) < 3:
            return float("nan")
    t = i + x[i] / (x[i] - x[i + 1])  # linear interpolation of each crossing
    # crossings closer than half the median period are noise on a slow edge: drop them
    period = median(np.diff(t))
    keep = [t[0]]
    for tc in t[1:]:
        if tc - keep[-1] > 0.5 * period:
            keep.append(tc)
    if len(keep) < 3:
        return float("nan")
    # the estimate is the span between the end crossings, so each end keeps, of its cluster (crossings within half a
    # period), the one on the grid of the others: a segment that starts on a creep's slow fall through the mean can
    # cross there twice, its first crossing 418 samples of 2626 off the grid (0.9 % low, harmonics 36 dB)
    step = median(np.diff(keep[1:-1])) if len(keep) > 3 else median(np.diff(keep))
    first = t[t <= keep[0] + 0.5 * period]
    last = t[(t >= keep[-1]) & (t <= keep[-1] + 0.5 * period)]
    keep[0] = first[np.argmin(np.abs(keep[1] - first - step))]
    keep[-1] = last[np.argmin(np.abs(last - keep[-2] - step))]
    return float((len(keep) - 1) * sample_rate / (keep[-1] - keep[0]))


def cycle_shape_error(x, ref, max_shift: int, oversample: int = 1) -> tuple[float, float]:
    """The limit cycle's shape error: min over one time shift s (|s| < max_shift samples, the same for the whole
    signal) of max |x(t + s) - ref(t)|, as a fraction of ref's range; and that shift (in x's samples). Why a shift: a
    note that speaks a millisecond early plays its whole cycle that much ahead, and a sample-by-sample max then reads
    the phase (up to the whole range at a slip edge), not the cycle; one shift for the whole span still sees any
    drift. The edges (max_shift samples) are left out of the comparison.

    ref may be sampled `oversample` times finer than x (ref[oversample * n] at x[n]'s time, e.g. a x100 FDM's every
    step): then the shift is searched on ref's grid, after the best whole-sample shift, within a sample of it. Why:
    a cycle's phase is not a whole number of samples, and at the capture's knee (the paper's scene: 1.1-1.9 % of the
    range a sample) the truth half a sample late reads 1.19 % against itself with whole-sample shifts."""
    x, ref = np.asarray(x, float), np.asarray(ref, float)
    os_ = int(oversample)
    if os_ < 1 or len(ref) < os_ * (len(x) - 1) + 1 or len(x) <= 2 * max_shift:
        raise ValueError(f"cycle_shape_error needs a signal of > {2 * max_shift} samples and a reference as long, "
                         f"sampled {os_} times finer")
    coarse = ref[::os_][:len(x)]
    span = float(coarse.max() - coarse.min())
    n = np.arange(max_shift, len(x) - max_shift)
    inner = coarse[n]
    best = min((float(np.max(np.abs(x[n + s] - inner))), s) for s in range(-max_shift + 1, max_shift))
    if os_ > 1:  # x[n + s] against ref at n - d / os_: a shift of s + d / os_ samples
        s = best[1]
        fine = [(float(np.max(np.abs(x[n + s] - ref[n * os_ - d]))), s + d / os_) for d in range(-os_ + 1, os_)
                if n[0] * os_ - d >= 0 and n[-1] * os_ - d < len(ref)]
        best = min([best] + fine)
    return best[0] / span if span > 0 else float("inf"), best[1]


def cents(f, f_ref) -> float:
    if not (f > 0 and f_ref > 0):
        return float("nan")
    return float(1200.0 * math.log2(f / f_ref))


def _spectrum(x, sample_rate):
    x = np.asarray(x, float)
    x = x[len(x) // 2:]
    x = x - x.mean()
    w = np.hanning(len(x))
    mag = np.abs(np.fft.rfft(x * w))
    freqs = np.fft.rfftfreq(len(x), 1 / sample_rate)
    return freqs, mag


def harmonic_error_db(x, ref, sample_rate: float, n_harmonics: int = 10, floor_db: float = -60.0) -> float:
    """Mean |dB difference| of the first harmonics' peak amplitudes (steady state), over harmonics above floor."""
    f0 = f0_estimate(ref, sample_rate)
    if not f0 > 0:
        return float("nan")
    fx, mx = _spectrum(x, sample_rate)
    _, mr = _spectrum(ref, sample_rate)
    df = fx[1] - fx[0]
    errs, top = [], mr.max()
    for h in range(1, n_harmonics + 1):
        fh = h * f0
        if fh >= sample_rate / 2:
            break
        lo, hi = int((fh - 0.3 * f0) / df), int((fh + 0.3 * f0) / df) + 1
        ar, ax = mr[lo:hi].max(), mx[lo:hi].max()
        if 20 * np.log10(ar / top + 1e-300) < floor_db:
            continue
        errs.append(abs(20 * np.log10((ax + 1e-300) / ar)))
    return float(np.mean(errs)) if errs else float("nan")


def log_spectral_distance(x, ref, sample_rate: float) -> float:
    """RMS over frequency of the dB difference of Welch power spectra (dB), bins within 80 dB of the peak."""
    nper = min(4096, len(ref))
    from scipy import signal as sps  # here only: scipy costs 0.3-0.9 s to import, and pitch solves use f0_estimate

    _, px = sps.welch(np.asarray(x, float), sample_rate, nperseg=nper)
    _, pr = sps.welch(np.asarray(ref, float), sample_rate, nperseg=nper)
    keep = pr > pr.max() * 1e-8
    if not keep.any():  # a reference so faint its power underflows to zero (F_B 1e-300): no spectrum to compare
        return float("nan")
    d = 10 * np.log10((px[keep] + 1e-300) / pr[keep])
    return float(np.sqrt(np.mean(d ** 2)))


def compare_signals(x, ref, sample_rate: float, pitch_signal_x=None, pitch_signal_ref=None) -> dict:
    """All metrics of x against ref. Pitch is measured on the optional pitch signals (default: x and ref)."""
    px = x if pitch_signal_x is None else pitch_signal_x
    pr = ref if pitch_signal_ref is None else pitch_signal_ref
    fx, fr = f0_estimate(px, sample_rate), f0_estimate(pr, sample_rate)
    return {
        "nmse": nmse(x, ref),
        "ncc_percent": ncc(x, ref),
        "f0_hz": fx,
        "f0_ref_hz": fr,
        "cents": cents(fx, fr),
        "harmonic_error_db": harmonic_error_db(x, ref, sample_rate),
        "lsd_db": log_spectral_distance(x, ref, sample_rate),
    }


# --- What a listener hears (docs/measures.md): timbre, pitch and onset, each well conditioned in the bow, unlike NMSE
# from rest (a bow 0.1 % off moves harmonics by <= 0.06 dB and the pitch by 0.3-1.2 cents, NMSE by 3e-3 to 0.1).

HARMONICS = 10
AUDIBLE_DB = -50.0  # harmonics of the truth below this (re its fundamental) are not scored


def harmonic_amplitudes(x, sample_rate: float, n: int = HARMONICS, f0: float | None = None) -> np.ndarray:
    """Amplitudes of harmonics 1..n, fitted by least squares at the signal's own pitch (f0, or measured by
    f0_estimate over all of x). Fitting each signal at its own pitch matters: at a shared pitch a 0.16 % pitch
    difference smears harmonic 10 over 1.6 cycles and reads as -17 dB. NaN at or above Nyquist or with no pitch."""
    x = np.asarray(x, float)
    f0 = f0_estimate(x, sample_rate, tail=1.0) if f0 is None else f0
    out = np.full(n, np.nan)
    if not f0 > 0 or len(x) < 4:
        return out
    m = min(n, int((sample_rate / 2) // f0))  # harmonics below Nyquist
    if m < 1:
        return out
    # over many periods the columns [1, cos k theta t, sin k theta t] are nearly orthogonal (the normal matrix ~
    # diag(N, N/2, ...)), so the normal equations lose nothing, and they need no design matrix: A^T x from the
    # harmonics' phasors (one complex exponential a sample, its powers by products) and A^T A from geometric sums in
    # closed form. A second of audio took 17 ms with the matrix of cosines and sines (--windows auto fits ~85 a
    # model and bow). A short or degenerate fit builds the matrix and goes to lstsq.
    theta = 2 * np.pi * f0 / sample_rate
    G = _normal_matrix(len(x), theta, m) if len(x) * f0 >= 4 * sample_rate else None
    if G is not None:
        d = np.diag(G)
        if np.linalg.cond(G / np.sqrt(np.outer(d, d))) >= 1e6:
            G = None
    if G is not None:
        e = np.exp(1j * theta * np.arange(len(x)))
        z, proj = e.copy(), np.empty(m, complex)
        for k in range(m):
            proj[k] = z @ x
            if k + 1 < m:
                z *= e
        c = np.linalg.solve(G, np.concatenate([[x.sum()], proj.real, proj.imag]))
    else:
        ph = theta * np.arange(len(x))[:, None] * np.arange(1, m + 1)[None, :]
        A = np.concatenate([np.ones((len(x), 1)), np.cos(ph), np.sin(ph)], axis=1)
        c, *_ = np.linalg.lstsq(A, x, rcond=None)
    out[:m] = np.hypot(c[1:m + 1], c[m + 1:])
    return out


def _normal_matrix(n: int, theta: float, m: int) -> np.ndarray | None:
    """A^T A for the columns [1, cos(k theta t), sin(k theta t)] (k = 1..m, t = 0..n-1), from the sums
    S(q) = sum_t e^(i q theta t) in closed form; None where a sum's ratio is too near 1 to divide by."""
    q = np.arange(2 * m + 1)
    z = np.exp(1j * theta * q)
    if np.abs(1 - z[1:]).min() < 1e-9:
        return None
    S = np.empty(2 * m + 1, complex)
    S[0] = n
    S[1:] = (1 - np.exp(1j * theta * q[1:] * n)) / (1 - z[1:])
    j = np.arange(1, m + 1)
    dif, tot = np.abs(j[:, None] - j[None, :]), j[:, None] + j[None, :]
    sign = np.sign(j[None, :] - j[:, None])  # k - j for the cos j sin k block
    G = np.empty((2 * m + 1, 2 * m + 1))
    G[0, 0] = n
    G[0, 1:m + 1] = G[1:m + 1, 0] = S[j].real
    G[0, m + 1:] = G[m + 1:, 0] = S[j].imag
    G[1:m + 1, 1:m + 1] = (S[dif].real + S[tot].real) / 2
    G[m + 1:, m + 1:] = (S[dif].real - S[tot].real) / 2
    cs = (S[tot].imag + sign * S[dif].imag) / 2  # sum cos(j theta t) sin(k theta t)
    G[1:m + 1, m + 1:] = cs
    G[m + 1:, 1:m + 1] = cs.T
    return G


def harmonic_levels(x, sample_rate: float, n: int = HARMONICS, f0: float | None = None) -> np.ndarray:
    """Levels of harmonics 1..n in dB re the signal's own fundamental (harmonic_amplitudes). NaN where x has no
    pitch."""
    amp = harmonic_amplitudes(x, sample_rate, n, f0)
    if not amp[0] > 0:
        return np.full(n, np.nan)
    return 20 * np.log10(np.maximum(amp, 1e-300) / amp[0])


def onset_time(x, sample_rate: float, f0: float | None = None, end: int | None = None) -> float:
    """The first time (s) a one-period RMS of x reaches half its final value (the RMS over the last tenth of x, or
    of x[:end] when the note's sustain ends at sample `end`, before a release); NaN for silence. The period is the
    signal's own (measured over its last half) unless f0 is given; the RMS window ends at the time reported."""
    x = np.asarray(x, float)
    if end is not None:
        x = x[:max(1, min(len(x), end))]
    f0 = f0_estimate(x, sample_rate) if f0 is None else f0
    if not f0 > 0:
        return float("nan")
    per = max(2, int(round(sample_rate / f0)))
    tail = x[-max(per, len(x) // 10):]
    final = float(np.sqrt(np.mean((tail - tail.mean()) ** 2)))
    if not final > 0 or len(x) < per:
        return float("nan")
    c = np.concatenate([[0.0], np.cumsum(x)])
    c2 = np.concatenate([[0.0], np.cumsum(x * x)])
    mean = (c[per:] - c[:-per]) / per
    rms = np.sqrt(np.maximum((c2[per:] - c2[:-per]) / per - mean ** 2, 0.0))
    hit = np.flatnonzero(rms >= 0.5 * final)
    return float((hit[0] + per) / sample_rate) if len(hit) else float("nan")


def onset_limit_ms(ref_ms: float) -> float:
    """The onset error a listener's target allows: max(5 ms, 2 % of the truth's onset)."""
    return max(5.0, 0.02 * ref_ms)


def harmonic_errors(levels, ref_levels) -> tuple[np.ndarray, bool]:
    """(|dB| per harmonic, NaN where not scored: harmonic 1, the reference level in both by construction, and those
    of the reference below AUDIBLE_DB; whether a scored harmonic is missing from `levels` entirely: NaN where the
    reference has one, as bad as it gets)."""
    heard = ref_levels >= AUDIBLE_DB
    heard[0] = False
    err = np.abs(levels - ref_levels)
    err[~heard] = np.nan
    return err, bool((np.isnan(levels) & heard).any())


def listener_errors(x, ref, sample_rate: float, steady_seconds: float = 1.0) -> dict:
    """What a listener hears of x against ref, both from the same start: pitch (cents), harmonics 1-10 (dB, those
    of ref above AUDIBLE_DB; each signal fitted at its own pitch) over the last `steady_seconds` (at most the last
    half), and the onset (ms). Keys: cents, harm_db (per harmonic, NaN where not scored), harm_db_median,
    harm_db_max, onset_ms, onset_ref_ms, onset_err_ms."""
    x, ref = np.asarray(x, float), np.asarray(ref, float)
    n = min(len(x), len(ref))
    x, ref = x[:n], ref[:n]
    k = min(int(steady_seconds * sample_rate), n // 2)
    sx, sr = x[n - k:], ref[n - k:]
    fx, fr = f0_estimate(sx, sample_rate, tail=1.0), f0_estimate(sr, sample_rate, tail=1.0)
    err, missing = harmonic_errors(harmonic_levels(sx, sample_rate, f0=fx), harmonic_levels(sr, sample_rate, f0=fr))
    scored = err[np.isfinite(err)]
    ox, orf = onset_time(x, sample_rate), onset_time(ref, sample_rate)
    return {
        "cents": cents(fx, fr),
        "harm_db": err.tolist(),
        "harm_db_median": median(scored) if len(scored) else (float("inf") if missing else 0.0),
        "harm_db_max": float("inf") if missing else (float(np.max(scored)) if len(scored) else 0.0),
        "onset_ms": 1e3 * ox,
        "onset_ref_ms": 1e3 * orf,
        "onset_err_ms": 1e3 * (ox - orf),
    }


SILENT = physics.SILENT


def late_rms(p) -> float:
    """p's RMS about its mean over its last half: how loud a note still is once its onset has passed."""
    p = np.asarray(p, float)
    return float(np.std(p[len(p) - len(p) // 2:]))


def note_sounds(p) -> bool:
    """Whether a note sounds: late_rms above SILENT (bench map's rule, and validation's where the truth rests)."""
    return late_rms(p) > SILENT


FRAME_SECONDS = 0.1  # a gesture is scored per 100 ms frame


def frame_errors(x, ref, sample_rate: float, frame: float = FRAME_SECONDS, harmonics: bool = True) -> dict:
    """x against ref per `frame`-second frame, as a gesture is scored: each frame's median harmonic error (dB) and
    |cents|, each signal fitted at its own pitch, over frames where ref sounds (RMS above 1 % of its loudest frame's),
    the first frame (the attack) left out. A frame's cents are NaN where either has no pitch there (fewer than three
    periods in the frame: a pitch would be noise). Keys: t (each frame's start, s), harm_db, cents (lists), frames,
    harm_db_median, harm_db_worst_frame, cents_median (over pitched frames; NaN where none is), unpitched_frames.
    harmonics False: the pitch alone (harm_db NaN), ~10x cheaper."""
    x, ref = np.asarray(x, float), np.asarray(ref, float)
    n = int(frame * sample_rate)
    starts = list(range(n, min(len(x), len(ref)) - n + 1, n))
    rms = np.array([np.std(ref[a:a + n]) for a in starts])
    t, harm, off = [], [], []
    for a, r in zip(starts, rms):
        if not r > 0.01 * rms.max():
            continue
        if harmonics:
            # the frame before it too, so that listener_errors' steady part (at most the last half) is the whole
            # frame: stick-slip at high force sounds 2-4 periods a frame (42 Hz at f0 100, F_B / w 1.1)
            e = listener_errors(x[a - n:a + n], ref[a - n:a + n], sample_rate, steady_seconds=frame)
            c, h = abs(float(e["cents"])), float(e["harm_db_median"])
        else:
            fx, fr = (f0_estimate(y[a:a + n], sample_rate, tail=1.0) for y in (x, ref))
            c, h = abs(cents(fx, fr)), float("nan")
        t.append(a / sample_rate)
        harm.append(h)
        off.append(c)
    pitched = np.isfinite(off)
    return {"t": t, "harm_db": harm, "cents": off, "frames": len(harm),
            "harm_db_median": median(harm) if harm else float("nan"),
            "harm_db_worst_frame": float(np.max(harm)) if harm else float("nan"),
            "cents_median": median(np.asarray(off)[pitched]) if pitched.any() else float("nan"),
            "unpitched_frames": int(np.sum(~pitched))}


# --- Speed at equal accuracy: one rule for `bench equal` and `compare` ---------------------------------------------


def accuracy(x, ref, sample_rate: float) -> dict:
    """The three errors an equal-accuracy claim is held to, of x against the truth ref: the median harmonic error
    (dB, listener_errors), the pitch error (|cents|) and NMSE."""
    le = listener_errors(x, ref, sample_rate)
    return {"harm_db": le["harm_db_median"], "cents": abs(le["cents"]), "nmse": nmse(x, ref)}


# The FDMs an equal-accuracy search tries, cheapest first (each costs less than the x100 truth beside it). x64 is
# there because, locked to the physics, a stick-slip tile's pitch is exact, and at 880 Hz no FDM up to x32 matches it:
# without it `bench equal` could only say "5-6x or more" for 17 model-pitches
EQUAL_OVERSAMPLES = (1, 2, 4, 8, 16, 32, 64)

# Two renders of equal accuracy differ by their storage (a float32 file against the float64 render it holds): 1 % of
# each error, or these floors, is no difference
EQUAL_FLOOR = {"harm_db": 1e-3, "cents": 1e-3, "nmse": 1e-9}


def as_accurate(a: dict, b: dict) -> bool:
    """Is a render with errors a (accuracy) at least as accurate as one with errors b on every one of them (up to 1 %
    or EQUAL_FLOOR)? An error b cannot state (NaN: no pitch, no harmonic above the floor) asks nothing."""
    return all(not math.isfinite(b[k]) or a[k] <= b[k] + max(0.01 * b[k], EQUAL_FLOOR[k]) for k in EQUAL_FLOOR)
