"""Rolling render: the operator applied window to window, each window seeded by the previous window's end state.

The audio samples sit at fixed offsets tau_j = j w / sr inside every window, so the trunk features there are
computed once per render and pitch; a window then costs one branch evaluation and a small matmul. No torch here; the
loops run compiled (`bowsynth.compiled`: src/core/rollout.cpp), or in numpy (`_roll_numpy`, the tests' readable reference).
"""

from __future__ import annotations

import numpy as np

from ...scene import Scene
from .basis import window_bases, numpy_operator
from .modelfile import OperatorModel
from .windows import FAIL_DOMAIN, FAIL_NONFINITE, max_windows, window_bounds, window_ends

# The compiled core has two loops: one voice after another (matrix-vector products) and every voice one window at a
# time (matrix-matrix products over the voices). Measured on the chorale's 172 voices at 92-660 Hz (benchmarks/
# chorale.py's piece; CPU shared): one voice after another took 0.019 / 0.049 / 0.20 / 0.41 / 0.85 / 1.69 s for
# 2 / 8 / 32 / 64 / 256 / 512 voices, the window-at-a-time loop 0.023 / 0.059 / 0.25 / 0.60 / 1.22 / 2.75 s. So
# all of a render's voices never go through the second in one call; renders use it on small groups (below), and
# loop="core-voices" / "core-batch" ask for either loop over all voices (the parity tests keep each honest).
# BATCH_FROM: the voices a test needs for the window-at-a-time loop to work on more than one block of voices.
BATCH_FROM = 8

# The compiled loops release the GIL and keep their workspaces per thread (rollout.cpp), so a render's voices roll on
# several cores. They go in groups of GROUP voices at about the same pitch, each group through the window-at-a-time
# loop: its products then run over GROUP voices at once (each weight loaded once for all of them), the group's voices
# need about as many windows, and its bases (GROUP pitches) stay in cache. Measured on 64 voices at 100-800 Hz (CPU
# time, one thread): voice after voice 1084x real time, all 64 window at a time 857x, groups of 2 / 4 / 8 / 16 sorted
# by pitch 1242x / 1560x / 1442x / 1307x (unsorted: 982x / 1197x / 1092x / 1046x). The groups are fixed by the
# voices' pitches alone and split over threads as whole groups, so a voice's samples never depend on the threads.
# A run of groups must hold MIN_THREAD_SAMPLES of work: below, starting a thread costs more than it saves. Per voice
# the work is n_samples (1 + WINDOW_SAMPLES / samples per window): a window's branch costs ~33k multiply-adds, a
# sample ~134 (benchmarks/core_speed.py), so a window weighs ~245 samples.
GROUP = 4
MIN_THREAD_SAMPLES = 100_000
WINDOW_SAMPLES = 245.0
PER_VOICE = (0, 4, 9, 10, 12, 13)  # the loops' per-voice inputs: x0, vidx, center, halfrange, pin, gain


def threads() -> int:
    """The cores a render may use (compiled.usable_cores: this process's CPU affinity), at most the threads
    compiled.share runs work on."""
    from ... import compiled

    return min(compiled.usable_cores(), compiled.SHARE_THREADS)


def voice_runs(work: np.ndarray, n_threads: int) -> list[tuple[int, int]]:
    """Contiguous runs [a, b) of items (voices, or groups of them) whose summed work is about equal, at most
    n_threads of them, none with less than MIN_THREAD_SAMPLES of work unless there is only one."""
    B = len(work)
    n = int(min(n_threads, B, max(1, work.sum() // MIN_THREAD_SAMPLES)))
    if n <= 1:
        return [(0, B)]
    cum = np.cumsum(work)
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, n) / n) + 1  # each run ends after the item that crosses
    # sorted(set()), not np.unique: np.unique of a plain array imports numpy.ma (8-16 ms of a render's process)
    bounds = sorted({0, B, *(min(int(c), B) for c in cuts)})
    runs = [[a, b] for a, b in zip(bounds[:-1], bounds[1:])]
    while len(runs) > 1:  # a run of too little work joins its lighter neighbour
        w = [cum[b - 1] - (cum[a - 1] if a else 0) for a, b in runs]
        i = int(np.argmin(w))
        if w[i] >= MIN_THREAD_SAMPLES:
            break
        j = i - 1 if i == len(runs) - 1 or (i > 0 and w[i - 1] <= w[i + 1]) else i + 1
        lo, hi = min(i, j), max(i, j)
        runs[lo:hi + 1] = [[runs[lo][0], runs[hi][1]]]
    return [(a, b) for a, b in runs]


def voice_groups(spw_voice: np.ndarray) -> list[np.ndarray]:
    """The voices' indices in groups of GROUP, by samples per window (pitch), slowest first."""
    order = np.argsort(-np.asarray(spw_voice), kind="stable")
    # within a group in row order: a voice's bits may depend on its place in the group's products, not on the path
    return [np.sort(order[a:a + GROUP]) for a in range(0, len(order), GROUP)]


def _roll_groups(args: tuple, n_threads: int) -> None:
    """The compiled window-at-a-time loop over voice_groups, over up to n_threads threads (as many as voice_runs finds
    worth it). Every group writes into the render's own rows of the outputs, in place.

    The per-voice inputs are put in the groups' order once, so each group is a slice of them (a group of rows that
    are not neighbours was copied out of every input for each group: 350 copies, 1.6 ms of a 42 ms roll of 64 voices
    at 100-800 Hz, with the GIL held). The threads take whole groups from one queue, heaviest first, as each is free:
    split in fixed runs by estimated work, one thread waited for the other ~2.8 ms of those 42 (the estimate is
    off by the CPU's vector width). A group's voices roll in one call whichever thread takes it, so their samples
    never depend on the threads."""
    from ... import compiled as core

    n_samples, spw, vidx, q, p, fail = args[1], args[2], args[4], args[-3], args[-2], args[-1]
    groups = voice_groups(spw[vidx])
    work = n_samples * (1 + WINDOW_SAMPLES / spw[vidx])
    order = np.concatenate(groups)
    if np.array_equal(order, np.arange(len(order))):  # one voice, or voices already in pitch order: views
        ins = args[:-3]
    else:
        ins = tuple(np.ascontiguousarray(v[order]) if i in PER_VOICE else v for i, v in enumerate(args[:-3]))
    ends = np.cumsum([len(g) for g in groups])
    spans = [(int(e) - len(g), int(e), g) for e, g in zip(ends, groups)]

    def run(k):
        a, b, g = spans[k]
        # the loop writes each voice into its own row of q, p and fail (rows = g): nothing to copy back
        core.roll(True, *[v[a:b] if i in PER_VOICE else v for i, v in enumerate(ins)], q, p, fail, g)

    group_work = np.array([work[g].sum() for g in groups])
    n_run = len(voice_runs(group_work, n_threads))
    if n_run == 1:
        for k in range(len(groups)):
            run(k)
        return
    # this thread takes groups too, heaviest first, while n_run - 1 others take the rest (compiled.share: with
    # Ctrl-C held, for an exception raised inside the threads' hand-over left its lock held)
    core.share(run, np.argsort(-group_work, kind="stable").tolist(), n_run)


def scene_bows(scene: Scene, spw: float, n_samples: int | None = None) -> np.ndarray:
    """The bow (beta, v_B) the operator applies in each window of a render of the scene: the controls at the
    window's middle (held over the window: second order in the window length; held at its start the error of a
    crescendo is 200x larger, docs/measures.md). (W, 2)."""
    starts, ends = window_bounds(spw, scene.n_samples if n_samples is None else n_samples)
    t = 0.5 * (starts + ends) / scene.sample_rate
    return np.stack([scene.fb_at(t) / scene.omega, scene.vb_at(t)], axis=1)


def applied_controls(scene: Scene, spw: float, bows: np.ndarray) -> dict:
    """Per output sample, the controls the operator applied (Render.controls): fb (m/s^2) and vb, piecewise constant
    per window."""
    n = scene.n_samples
    starts, ends = window_bounds(spw, n)
    lens = np.minimum(ends, n) - starts
    rep = lambda v: np.repeat(v[:len(lens)], lens)[:n]  # noqa: E731
    return {"fb": rep(bows[:, 0] * scene.omega), "vb": rep(bows[:, 1])}


def _window_bows(model: OperatorModel, B: int, W: int, params) -> np.ndarray:
    """params as (B, W, 2) bows per window: None (a range model's own centre; ignored by a point model), one bow for
    all, one per voice (B, 2), or per voice and window (B, W', 2), padded with each voice's last."""
    d = model.domain
    if params is None:
        params = [d.beta, d.vb]
    par = np.asarray(params, float)
    if par.ndim == 1:
        par = np.broadcast_to(par, (B, 2))
    if par.ndim == 2:
        par = np.broadcast_to(par[:, None, :], (B, W, 2))
    if par.shape[1] < W:
        par = np.concatenate([par, np.repeat(par[:, -1:], W - par.shape[1], axis=1)], axis=1)
    return par[:, :W]


def _voice_bases(model: OperatorModel, B: int, dtau, window):
    """B voices' spacings and windows (broadcast), their distinct (spacing, window) pairs, and the pairs' bases
    (basis.window_bases: cached per model, so a second call with the same voices costs a key's comparison)."""
    dt = np.broadcast_to(np.asarray(dtau, dtype=float), (B,))
    T = numpy_operator(model).window
    win = np.broadcast_to(np.asarray(T if window is None else window, dtype=float), (B,))
    if np.any(win > T * (1 + 1e-12)) or not np.all(win > 0):
        raise ValueError(f"a window must be > 0 and at most the model's {T:.6g} in tau")
    pairs = sorted(set(zip(dt.tolist(), win.tolist())))  # the distinct (spacing, window): one basis each
    return dt, win, pairs, window_bases(model, [(d, None if w == T else w) for d, w in pairs])


def prepare(model: OperatorModel, dtau, window=None) -> None:
    """What a rollout of these voices (their spacings dtau and windows, as rollout_states takes them) computes before
    its loop: the weights converted and the window bases, so that timing the rollout measures the loop. Cached: a
    second render of the same pitches costs ~20 us here, where a one-sample rollout to warm up cost ~0.2 ms."""
    _voice_bases(model, np.size(dtau), dtau, window)


def rollout_states(model: OperatorModel, x0: np.ndarray, n_samples: int, dtau, check_domain: bool = True,
                   loop: str = "auto", params=None, window=None):
    """Roll the operator from states x0 (B, 2) for n_samples samples spaced dtau in tau (one spacing for all voices,
    or one per voice: voices at different pitches roll in one batch).

    loop: 'core' (the compiled loops, src/core/rollout.cpp: voices in groups at about the same pitch through the
    window-at-a-time loop, the groups over this process's cores; 'auto' is the same), 'core-1' (the same groups on this
    thread alone), 'core-voices' (the voice-after-voice loop), 'core-batch' (every voice in one window-at-a-time call),
    or 'numpy' (`_roll_numpy`, the readable reference the tests hold the compiled loops to).
    Returns q, p (B, n_samples) float32 and fail (B, 2) int: per voice the first sample of the window where the
    rollout left the model's domain or went non-finite, and the reason (a key of FAILURES), or (-1, 0). A failed
    voice stops there (its later samples are NaN); the other voices go on.
    params: a range model's bows (beta, v_B): one (2,), per voice (B, 2) or per voice and window (B, W, 2) (see
    scene_bows); None plays the model's own (centre) bow. They are not checked against the model's box here.
    window: each voice's window in tau (one for all, or one per voice; None: the model's trained T), at most T: a
    voice locked to its sounding period (windows.locked_window).
    """
    x = np.array(x0, dtype=float).reshape(-1, 2)
    B = len(x)
    dt, win, pairs, stack = _voice_bases(model, B, dtau, window)
    at = {pw: i for i, pw in enumerate(pairs)}
    vidx = np.array([at[pw] for pw in zip(dt.tolist(), win.tolist())], dtype=np.int64)
    spw, n_lo, Bq, Bp, endb, endlin = stack
    vidx = np.ascontiguousarray(vidx, dtype=np.int64)
    op = numpy_operator(model)
    q = np.empty((B, n_samples), np.float32)
    p = np.empty((B, n_samples), np.float32)
    fail = np.tile(np.array([-1, 0], np.int64), (B, 1))  # the loops write only the voices that fail
    d = model.domain
    W = max_windows(n_samples, spw)  # as many windows as the loops may start
    pin, gain, center, halfrange = op.window_inputs(_window_bows(model, B, W, params))
    args = (x, n_samples, spw, n_lo, vidx, Bq, Bp, endb, endlin, center, halfrange, op.ff, pin, gain, *op.weights,
            np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi]), np.ascontiguousarray(d.mask), bool(check_domain), q, p, fail)
    if loop in ("auto", "core", "core-1"):
        _roll_groups(args, 1 if loop == "core-1" else threads())
    elif loop in ("core-voices", "core-batch"):
        from ... import compiled as core

        core.roll(loop == "core-batch", *args, np.arange(B, dtype=np.int64))
    elif loop == "numpy":
        _roll_numpy(*args)
    else:
        raise ValueError(f"loop must be auto, core, core-1, core-voices, core-batch or numpy, got {loop!r}")
    for b in np.flatnonzero(fail[:, 0] >= 0):
        q[b, fail[b, 0]:] = np.nan
        p[b, fail[b, 0]:] = np.nan
    return q, p, fail


BLOCK = 256  # windows per pass of the two-pass loops: bounds the stored branch outputs (B x BLOCK x 2k floats)


def _roll_numpy(x0, n_samples, spw, n_lo, vidx, Bq, Bp, endb, endlin, center, halfrange, ff, pin, gain, Gw, Gb, Hw,
                Hb, Ow, Ob, box, mask, check, q_out, p_out, fail):
    """kernels.roll_batch in numpy (same arguments, same float32 arithmetic up to rounding), in two passes per block
    of BLOCK windows.

    First the chain: every running voice one window at a time, the branch as matrix products over the voices, the
    end state from the window's last offset only (endb, endlin), keeping each window's start state and branch
    output. Then the samples, voice by voice: all of a voice's windows of the block in one matrix product with its
    pitch's basis. Writing samples inside the chain touches every pitch's basis once per window (23 MB for 100
    pitches: memory-bound), and per window numpy's call overhead outweighs a small product.
    """
    B = x0.shape[0]
    k = endb.shape[-1]
    width = Hw.shape[-1]
    n_hi = np.ceil(spw).astype(np.int64)
    sp, nl = spw[vidx], n_lo[vidx]
    W = max_windows(n_samples, sp)
    ends = window_ends(sp, W)
    starts = np.concatenate([np.zeros((B, 1), np.int64), ends[:, :-1]], axis=1)
    jlen = ends - starts - nl[:, None]  # 0: a window of n_lo samples, 1: of n_hi
    n_run = (starts < n_samples).sum(axis=1)  # windows each voice needs
    # per window as few numpy calls as possible (each costs microseconds): the features' scaling folded into ff,
    # and the end state as one product of [o_q, o_p, q0, p0, 1] with E[pitch, length] (float64, kernels._end_state)
    # (the scaling varies per window only for a bow-scaled range model: then it is applied per window)
    per_window = not (np.all(center == center[:1, :1]) and np.all(halfrange == halfrange[:1, :1]))
    c0, h0 = (center[0, 0], halfrange[0, 0]) if center.size else (np.zeros(2), np.ones(2))
    ffs, off = ff[:2] / h0[:, None], (c0 / h0) @ ff[:2]
    ffp = ff[2:]  # a range model's bow inputs (pin) enter the same features
    last_w = pin.shape[1] - 1
    E = np.zeros((len(spw), 2, 2 * k + 3, 2))
    E[:, :, :k, 0], E[:, :, k:2 * k, 1] = endb[:, :, 0], endb[:, :, 1]
    E[:, :, 2 * k, 0], E[:, :, 2 * k + 1, 0], E[:, :, 2 * k + 2, 0] = endlin[..., 0], endlin[..., 1], endlin[..., 2]
    E[:, :, 2 * k, 1], E[:, :, 2 * k + 1, 1], E[:, :, 2 * k + 2, 1] = -endlin[..., 5], endlin[..., 4], endlin[..., 3]
    lo, span = np.array([box[0], box[2]]), np.array([box[1] - box[0], box[3] - box[2]])
    g = mask.shape[0]
    done = np.zeros(B, np.int64)  # windows computed per voice (the last one may be where it failed)
    x = x0.astype(np.float64).copy()
    alive = np.ones(B, bool)
    rows = np.arange(B)
    pm = np.array([1, -1], np.float32)
    for w0 in range(0, W, BLOCK):
        w1 = min(w0 + BLOCK, W)
        O_blk = np.empty((B, w1 - w0, 2 * k), np.float32)
        X_blk = np.empty((B, w1 - w0, 2), np.float64)
        G_blk = np.empty((B, w1 - w0), np.float64)
        act = rows
        for win in range(w0, w1):
            if win >= n_run.min() or not alive.all():
                act = rows[alive & (win < n_run)]
                if not act.size:
                    break
            xa = x[act]
            X_blk[act, win - w0] = xa
            wi = min(win, last_w)
            if per_window:
                z = ((xa - center[act, wi]) / halfrange[act, wi]) @ ff[:2]
            else:
                z = xa @ ffs - off
            if ffp.shape[0]:
                z += pin[act, wi] @ ffp
            ga = gain[act, wi]
            h = np.concatenate([np.cos(z), np.sin(z)], axis=1).astype(np.float32)
            T = np.tanh(h @ Gw + Gb)
            V = T[:, width:2 * width]
            U = T[:, :width] - V  # modified MLP: h = v + tanh(z) (u - v); U is kept as u - v
            hh = V + T[:, 2 * width:] * U
            for layer in range(Hw.shape[0]):
                hh = V + np.tanh(hh @ Hw[layer] + Hb[layer]) * U
            O = (hh @ Ow + Ob) * ga[:, None].astype(np.float32)  # (A, 2k)
            O_blk[act, win - w0] = O
            G_blk[act, win - w0] = ga
            done[act] = win + 1
            nx = np.einsum("ai,aij->aj", np.concatenate([O, xa, ga[:, None]], axis=1),
                           E[vidx[act], jlen[act, win]])
            ok = np.isfinite(nx).all(axis=1)
            if check:
                cell = (nx - lo) / span
                inside = ok & (cell >= 0).all(axis=1) & (cell <= 1).all(axis=1)
                ij = np.minimum((np.where(inside[:, None], cell, 0) * g).astype(np.int64), g - 1)
                ok_dom = inside & mask[ij[:, 0], ij[:, 1]]
                last = ends[act, win] >= n_samples  # no window follows: nothing to check
                stop = ~ok | ~(ok_dom | last)
            else:
                stop = ~ok
            if stop.any():
                bad, out = ~ok, stop & ok
                fail[act[bad], 0], fail[act[bad], 1] = starts[act[bad], win], FAIL_NONFINITE
                fail[act[out], 0], fail[act[out], 1] = ends[act[out], win], FAIL_DOMAIN
                alive[act[stop]] = False
            x[act] = nx
        for b in range(B):
            wb = min(w1, int(done[b]))
            if wb <= w0:
                continue
            nw, nh = wb - w0, n_hi[vidx[b]]
            xf = X_blk[b, :nw].astype(np.float32)
            ones = G_blk[b, :nw, None].astype(np.float32)  # the bias rows take the gain
            # (nw, n_hi): one row per window, this pitch's columns only (the stack is padded to the longest window)
            Tq = np.concatenate([O_blk[b, :nw, :k], xf, ones], axis=1) @ Bq[vidx[b], :, :nh]
            Tp = np.concatenate([O_blk[b, :nw, k:], xf[:, ::-1] * pm, ones], axis=1) @ Bp[vidx[b], :, :nh]
            # sample i lies in window w at offset i - starts[w]
            first, last = int(starts[b, w0]), min(int(ends[b, wb - 1]), n_samples)
            lens = np.minimum(ends[b, w0:wb], last) - starts[b, w0:wb]
            flat = np.repeat(np.arange(nw) * nh - (starts[b, w0:wb] - first), lens) + np.arange(last - first)
            q_out[b, first:last] = Tq.ravel()[flat]
            p_out[b, first:last] = Tp.ravel()[flat]


# Voices of one model roll together to the longest one's length; a score's notes differ up to 8x in length (the
# chorale's sustains: 12.5 M samples rolled for 7.1 M wanted), so they roll in groups of similar length instead,
# each group's longest at most this much longer than its shortest
LENGTH_SLACK = 1.15


def length_buckets(lengths: list[int]) -> list[np.ndarray]:
    """The voices' indices in groups whose longest is at most LENGTH_SLACK times the shortest, shortest first."""
    order = np.argsort(lengths, kind="stable")
    out, start = [], 0
    for k in range(1, len(order) + 1):
        if k == len(order) or lengths[order[k]] > LENGTH_SLACK * lengths[order[start]]:
            out.append(order[start:k])
            start = k
    return out
