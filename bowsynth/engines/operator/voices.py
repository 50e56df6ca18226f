"""Voices that play block by block: the live engine's (`bowsynth.live.Stream`) and a pitch curve's
(`curve.render_curve`), on arrays prepared beforehand (`bank.VoiceBank`), so that an audio callback creates no array
and runs no Python per window.

The loop is the compiled core's (src/core/voices.cpp, `_core.Voices`): a window is the rollout's own
(`roll_voices`' body) and the FDM the core's step. What it adds is only the bookkeeping a stream needs and a whole
render does not: a voice's window partition continues across blocks (window w of a note starts at the sample nearest
w T from the note's start, exactly as offline, so the live samples are the offline samples), the window's samples
wait in the voice's buffer until the blocks reach them, and a voice changes engine (the flow at the bow's rest point
-> operator sustain -> FDM release) at a sample of its own. Here: the codes the Python side writes into a slot (the
core has the same; a test checks they agree) and the core's small helpers.
"""

from __future__ import annotations

from ... import compiled as core

FREE, OPERATOR, FDM, REST = 0, 1, 2, 3  # a slot's mode (REST: the flow at the bow's rest point, then the operator)
REST_COLS = 10  # rest[slot]: the rest flow's step (7: M, k, q_s; core.rest_coefficients), its radius, d, step's dtau
R_RADIUS, R_D, R_DTAU = 7, 8, 9
HELD, CURVE, LIVE = 0, 1, 2  # a slot's pitch: constant, breakpoints (a scene's f0 curve), bend and vibrato (play)
# pp[slot] columns: the note's f0 (Hz), F_B / w, then for LIVE the pitch bend's ramp (from, to in semitones, its
# start in the note's samples), the vibrato depth's (from, to in semitones), its start, the vibrato rate (Hz), and the
# ramps' length (samples)
P_F0, P_BETA, P_B0, P_B1, P_BT, P_D0, P_D1, P_DT, P_RATE, P_RAMP = range(10)
P_COLS = 10
WHY_OK, WHY_FALLBACK = 0, 1  # why[slot]: the operator left its states and the FDM finished the note


def dc_block(x, n: int, r: float, state, y) -> None:
    """y[:n] = the causal DC blocker y[i] = x[i] - x[i - 1] + r y[i - 1] of x[:n] (float64 in, float32 out), its
    memory in state (x, y)."""
    core.load().dc_block(x, n, r, state, y)


def pick_slot(mode, end, pos, start) -> int:
    """A free slot; else the one to steal: the releasing voice nearest its end, else the oldest."""
    return core.load().pick_slot(mode, end, pos, start)


def ramp(a: float, b: float, t0: float, length: float, s: float) -> float:
    """A live pitch control at the note's sample s: a until t0, then linear to b over `length` samples."""
    return core.load().ramp(a, b, t0, length, s)
