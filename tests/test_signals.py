"""Ctrl-C and SIGTERM sent to real bowsynth processes in each phase: one line, exit 130 / 143, no temp file, the old
output untouched, training's checkpoint kept."""

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

CODE = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated")}


def _start(args, tmp_path, **kw):
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir(exist_ok=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), TMPDIR=str(tmpdir), PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "bowsynth", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def _handlers_installed(proc, timeout=120):
    """Wait until the process has installed its SIGTERM handler (read from /proc): from then on a signal is
    bowsynth's to handle, whatever phase it lands in."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        try:
            caught = int(Path(f"/proc/{proc.pid}/status").read_text().split("SigCgt:")[1].split()[0], 16)
        except (FileNotFoundError, IndexError):
            caught = 0
        if caught & (1 << (signal.SIGTERM - 1)):
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("bowsynth never installed its signal handlers")


def _stop(proc, sig, timeout=60):
    proc.send_signal(sig)
    # the bound: the long work below would run for minutes; a handled signal ends it within seconds
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def _check(code, err, sig):
    want, word = CODE[sig]
    assert code == want, err
    assert err.strip() == word or (err.count("\n") == 1 and word in err), err
    assert "Traceback" not in err


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_during_a_long_fdm_render(sig, tmp_path):
    out = tmp_path / "x.wav"
    out.write_bytes(b"precious")
    # ~1.8e9 scheme steps: minutes of compiled FDM (hence --force); chunked, so the signal lands within a chunk
    proc = _start(["render", "--method", "fdm", "--oversample", "200", "-d", "200", "--force", str(out)], tmp_path)
    _handlers_installed(proc)
    time.sleep(4)  # into the compiled loop (start-up takes ~0.5-1 s)
    code, _, err = _stop(proc, sig)
    _check(code, err, sig)
    assert out.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tmp", "x.wav"] and not list((tmp_path / "tmp").iterdir())


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
def test_sigterm_during_compare_high_reference(tmp_path):
    from bowsynth import Scene, render_fdm
    from bowsynth.io.audio import write_wav

    wav = tmp_path / "long.wav"
    write_wav(wav, render_fdm(Scene(duration=60.0)))  # its x100 reference: 2.6e8 steps, ~20 s
    proc = _start(["compare", str(wav), "--reference", "high", "--plot", str(tmp_path / "p.png")], tmp_path)
    _handlers_installed(proc)
    time.sleep(4)
    code, out, err = _stop(proc, signal.SIGTERM)
    _check(code, err, signal.SIGTERM)
    assert not out and not (tmp_path / "p.png").exists()


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_while_blocked_writing_to_a_fifo(sig, tmp_path):
    """No reader on the FIFO: bowsynth blocks opening it after rendering; a signal must still end it cleanly,
    leave the FIFO a FIFO and remove its private temp file."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    proc = _start(["render", "--method", "fdm", "-d", "0.5", str(fifo)], tmp_path)
    _handlers_installed(proc)
    t0 = time.time()
    while not list((tmp_path / "tmp").iterdir()) and time.time() - t0 < 120:  # the temp file: writing has begun
        time.sleep(0.05)
    time.sleep(0.5)
    code, _, err = _stop(proc, sig)
    _check(code, err, sig)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert not list((tmp_path / "tmp").iterdir())


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
@pytest.mark.parametrize("delay", [0.0, 4.0], ids=["while-torch-loads", "during-data-preparation"])
def test_sigint_during_training_ends_in_one_line(delay, tmp_path):
    # a million FDM trajectories: data preparation alone would take many minutes. At once, training is still importing
    # torch, which holds the signal (errors.held) and then ends cleanly: cut half-way, the import left a warning
    # line. A process killed by the signal after printing its line (1 run in 5 under load): the test below. After 4 s,
    # in the threaded FDM data: once (CI) hung for good, a lock of concurrent.futures left held (the tests of share)
    out = tmp_path / "m.safetensors"
    proc = _start(["train", "--fb", "100", "--width", "16", "--depth", "2", "--n-data", "1000000", "--steps", "5",
                   "--quiet", "--out", str(out)], tmp_path)
    _handlers_installed(proc)
    time.sleep(delay)
    code, _, err = _stop(proc, signal.SIGINT)
    assert code == 130 and err == "interrupted\n", (code, err)
    assert not out.exists()


CTRL_C_AT = {
    # a namedtuple's or a dataclass's methods are made by exec() of a string while modules import: a Ctrl-C landing
    # there left CPython's 'unhandled KeyboardInterrupt' flag set, and `python -m` ended killed by SIGINT (-2) after
    # printing its line, not with exit 130 (the test above, 1 run in 5 under load)
    "inside-exec": "    exec('os.kill(os.getpid(), signal.SIGINT)\\nfor _ in range(9): pass', globals())",
    # an import cut half-way leaves its .pyc open: 'warning: unclosed file' beside the line (1 run in 27)
    "with-a-file-open": "    f = open(__file__, 'rb')\n    os.kill(os.getpid(), signal.SIGINT)",
}


@pytest.mark.parametrize("where", list(CTRL_C_AT))
def test_a_ctrl_c_where_the_flaky_runs_took_it_exits_130_in_one_line(where, tmp_path):
    """The flaky cases of the test above, made certain: the command's work replaced by the code the signal landed in."""
    (tmp_path / "ctrl_c_at.py").write_text(
        "import os, signal, sys\nimport bowsynth.cli.main as m\n"
        f"def app(**kw):\n{CTRL_C_AT[where]}\n"
        "m.app = app\nsys.argv = ['bowsynth', 'list']\nm.main()\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    proc = subprocess.run([sys.executable, "-m", "ctrl_c_at"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=120)
    assert (proc.returncode, proc.stderr) == (130, "interrupted\n")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
def test_sigterm_during_training_keeps_a_checkpoint(tmp_path):
    out = tmp_path / "t.safetensors"
    ckpt = tmp_path / "t.ckpt.safetensors"
    proc = _start(["train", "--fb", "100", "--width", "16", "--depth", "2", "--n-data", "64", "--out", str(out),
                   "--quiet", "--steps", "1000000", "--minutes", "10", "--checkpoint-every", "0.5"], tmp_path)
    _handlers_installed(proc)
    t0 = time.time()
    while not ckpt.exists() and time.time() - t0 < 180:  # training proper has begun
        time.sleep(0.2)
    code, _, err = _stop(proc, signal.SIGTERM)
    assert code == 143, err
    assert err.count("\n") == 1 and "terminated at step" in err and "checkpoint saved" in err and "--resume" in err
    assert ckpt.exists() and not out.exists()
    from safetensors import safe_open

    with safe_open(str(ckpt), framework="pt") as f:
        assert json.loads(f.metadata()["bowsynth_checkpoint"])["step"] > 0
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_fdm_in_chunks_equals_one_call(monkeypatch):
    """The FDM runs in chunks so that signals land between them; chunking must not change a sample, also when
    the bow follows a curve (the chunk's start time carries over)."""
    import numpy as np

    from bowsynth import Scene
    from bowsynth.engines import fdm

    sc = Scene(fb=[[0.0, 50.0], [0.05, 300.0]], vb=[[0.0, 0.1], [0.08, 0.25]], duration=0.1)
    monkeypatch.setattr(fdm, "CHUNK_STEPS", 10**12)
    whole = fdm.render_fdm(sc, oversample=3)
    monkeypatch.setattr(fdm, "CHUNK_STEPS", 1001)  # 333 samples a chunk
    parts = fdm.render_fdm(sc, oversample=3)
    np.testing.assert_array_equal(whole.q, parts.q)
    np.testing.assert_array_equal(whole.p, parts.p)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_stems_are_written_all_or_none(sig, tmp_path):
    """A signal while 150 stems are being written leaves the stems directory as it was (once it left 20 of them and
    no notes.json): here it held one old stem, which is kept, and nothing new."""
    voices = "".join(f'[[voice]]\nname = "v{i}"\nf0 = {100 + i}.0\nbeta = 0.159155\nduration = 0.3\n'
                     for i in range(150))
    (tmp_path / "many.toml").write_text(voices)
    st = tmp_path / "st"
    st.mkdir()
    (st / "old.wav").write_bytes(b"an earlier stem")
    proc = _start(["score", "--score", "many.toml", "--mix", "m.wav", "--stems", "st"], tmp_path)
    _handlers_installed(proc)
    t0 = time.time()
    while time.time() - t0 < 300:  # wait until the staging directory holds some stems: mid-write
        stages = list(st.glob(".staging-*"))
        if stages and len(list(stages[0].glob("*.wav"))) >= 10:
            break
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.005)
    else:
        raise AssertionError("never saw the stems being written")
    code, out, err = _stop(proc, sig)
    _check(code, err, sig)
    assert sorted(p.name for p in st.iterdir()) == ["old.wav"] and (st / "old.wav").read_bytes() == b"an earlier stem"
    assert not (tmp_path / "m.wav").exists()


@pytest.fixture
def raising_handlers():
    """The CLI's handlers (raise KeyboardInterrupt / Terminated), restored after the test."""
    from bowsynth.cli.main import _install_signal_handlers

    old = _install_signal_handlers()
    yield
    for sig, h in old.items():
        signal.signal(sig, h)


def _work(log, n_items, signal_at=None, sig=signal.SIGINT):
    """share() over n_items of 10 ms each on 3 threads; the item signal_at sends sig to the whole process (the kernel
    picks the thread) from whichever thread runs it. log["ran"]: the items run; log["seen"]: per call of the handler,
    the items running as it ran."""
    import threading

    from bowsynth.compiled import share

    log.update(ran=[], seen=[])
    running, lock = [0], threading.Lock()

    def run(i):
        with lock:
            running[0] += 1
        if i == signal_at:
            os.kill(os.getpid(), sig)
        time.sleep(0.01)
        with lock:
            running[0] -= 1
            log["ran"].append(i)

    handler = signal.getsignal(sig)

    def watch(signum, frame):  # the handler installed before, wrapped: how many items it interrupted
        log["seen"].append(running[0])
        if callable(handler):
            handler(signum, frame)

    signal.signal(sig, watch)
    try:
        share(run, range(n_items), 3)
    finally:
        signal.signal(sig, handler)


def test_shared_work_runs_every_item_once_over_the_threads():
    import threading

    from bowsynth.compiled import share

    who, lock = {}, threading.Lock()

    def run(i):
        time.sleep(0.005)
        with lock:
            who.setdefault(i, []).append(threading.get_ident())

    done = []
    share(run, range(40), 3, on_item=done.append)
    assert sorted(who) == list(range(40)) and all(len(v) == 1 for v in who.values())
    assert len({t for v in who.values() for t in v}) > 1  # the pool took items too
    assert done == sorted(done) and done[-1] == 40 and len(done) < 40  # this thread's items, counting all, and the end


def test_a_threads_error_is_raised_once_every_thread_is_back():
    from bowsynth.compiled import share

    ran = []

    def run(i):
        time.sleep(0.01)
        if i == 3:
            raise ValueError("item 3")
        ran.append(i)

    with pytest.raises(ValueError, match="item 3"):
        share(run, range(200), 3)
    n = len(ran)
    time.sleep(0.1)
    assert len(ran) == n < 20  # nothing still running, and the rest not taken


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("foreign", [False, True], ids=["threads-of-its-own", "beside-a-thread-that-may-take-it"])
def test_a_signal_during_shared_work_acts_once_the_threads_are_back(sig, foreign, raising_handlers):
    """The handler (the CLI's: it raises) runs after share's threads are back, never in the middle of handing
    items over (a KeyboardInterrupt there left concurrent.futures' locks held: the process hung, CI); the work stops
    within an item per thread. A thread that does not block the signal (torch's, say) may be the one handed it."""
    import threading

    from bowsynth.errors import Terminated

    gone, log = threading.Event(), {}
    if foreign:
        threading.Thread(target=gone.wait, daemon=True).start()
    try:
        with pytest.raises(Terminated if sig == signal.SIGTERM else KeyboardInterrupt):
            _work(log, 200, signal_at=5, sig=sig)
    finally:
        gone.set()
    assert log["seen"] == [0]  # once, with no item running
    assert 5 in log["ran"] and len(log["ran"]) < 20


def test_a_handler_that_returns_leaves_the_work_done():
    """A handler that only notes the signal: share() still runs every item (the pool stopped taking them)."""
    log = {}
    old = signal.signal(signal.SIGINT, lambda s, f: None)
    try:
        _work(log, 60, signal_at=5)
    finally:
        signal.signal(signal.SIGINT, old)
    assert sorted(log["ran"]) == list(range(60)) and log["seen"] == [0]


FDM_UNDER_FIRE = """
import os, random, signal, sys, time
import numpy as np
from bowsynth.cli.main import _install_signal_handlers
from bowsynth.engines.fdm import fdm_batch
_install_signal_handlers()
# the timer's handler only sends the signal: the CLI's handler raises wherever the main thread then is
signal.signal(signal.SIGALRM, lambda *a: os.kill(os.getpid(), signal.SIGINT))
n = 20000
q0, p0 = np.random.default_rng(0).normal(0, 0.01, n), np.zeros(n)
run = lambda: fdm_batch(q0, p0, 33, 4, 1e-6, 2 * np.pi * 100, 100.0, 0.2, 100.0)
t0 = time.perf_counter()
whole = run()
full = time.perf_counter() - t0
rng, cut = random.Random(int(sys.argv[1])), 0
for i in range(25):
    again = None
    try:
        # every other one in the first 2 %: where the threads start and the work is handed out
        signal.setitimer(signal.ITIMER_REAL, rng.uniform(0, (1.2 if i % 2 else 0.02) * full))
        again = run()
        signal.setitimer(signal.ITIMER_REAL, 0)
        time.sleep(0.01)  # a timer that fired as the run ended: its signal lands here
    except KeyboardInterrupt:
        cut += 1
    if again is not None:
        assert all(np.array_equal(a, b) for a, b in zip(whole, again))
print(cut)
"""


def test_ctrl_c_at_random_moments_of_the_threaded_fdm_always_ends_it_cleanly(tmp_path):
    """25 Ctrl-Cs, each at a random moment of a threaded FDM batch (training's data): each run ends with
    KeyboardInterrupt or its whole result; none with another error (RuntimeError: release unlocked lock) or a hang
    (a lock left held), as when an interrupt could land inside concurrent.futures (CI; the tests of share above)."""
    (tmp_path / "under_fire.py").write_text(FDM_UNDER_FIRE)
    proc = subprocess.run([sys.executable, "under_fire.py", "52"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert 10 <= int(proc.stdout) <= 25  # most of them cut a run short
