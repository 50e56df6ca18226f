"""Odd environments (issue 26): a cache file that is a FIFO, a user with no home directory."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bowsynth.io import cache

ROOT = Path(__file__).resolve().parents[1]


def _env(**kw):
    env = {k: v for k, v in os.environ.items() if k not in ("HOME", "XDG_CACHE_HOME", "BOWSYNTH_CACHE")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(kw)
    return env


def test_a_cache_file_that_is_a_fifo_is_ignored_not_waited_on(tmp_path):
    d = tmp_path / "cache"
    d.mkdir()
    os.mkfifo(d / "sounding-ratio.json")
    r = subprocess.run([sys.executable, "-m", "bowsynth", "render", "--pitch", "A3", "--method", "fdm", "-d", "0.1",
                        str(tmp_path / "a.wav")], env=_env(BOWSYNTH_CACHE=str(d)), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert "f0 224.3" in r.stdout and (tmp_path / "a.wav").stat().st_size > 0


def test_a_user_with_no_home_gets_no_cache_and_renders(tmp_path, monkeypatch, capsys):
    from conftest import run_main

    def no_home():  # what pathlib raises for a user with no HOME and no passwd entry
        raise RuntimeError("Could not determine home directory")

    for k in ("HOME", "XDG_CACHE_HOME", "BOWSYNTH_CACHE"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setattr(Path, "home", staticmethod(no_home))
    assert cache.cache_dir() is None
    code, out, err = run_main(["render", "--pitch", "A2", "--method", "fdm", "-d", "0.1", str(tmp_path / "b.wav")],
                              capsys, monkeypatch)
    assert code == 0 and "pitch 110.00 Hz" in out, err


@pytest.mark.parametrize("junk", [b"[" * 100000, b"\xff\xfe not utf-8", b'{"version": 1}'])
def test_a_damaged_cache_table_is_ignored(tmp_path, monkeypatch, junk):
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    (tmp_path / "t.json").write_bytes(junk)
    t = cache.DiskTable("t", "v1")
    assert t.get("k") is None
    t.put("k", 1)
    assert cache.DiskTable("t", "v1").get("k") == 1


@pytest.mark.parametrize("user", [None, "2"])
def test_numpy_blas_runs_on_one_thread_unless_the_user_says_otherwise(user):
    """OpenBLAS's own threads spin for cores another process holds (a 44100 x 21 product: 1380 ms against 1.3 ms
    on one thread with a training beside it, measured): importing bowsynth before numpy keeps numpy's BLAS on one
    thread, and a user's own OPENBLAS_NUM_THREADS stands."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if user is not None:
        env["OPENBLAS_NUM_THREADS"] = user
    # the threads OpenBLAS runs, asked of the library numpy loaded (its getter, where the build exports one)
    code = ("import bowsynth, numpy, ctypes, os\n"
            "libs = sorted({w for w in open('/proc/self/maps').read().split() if 'openblas' in w})\n"
            "n = -1\n"
            "for name in ('scipy_openblas_get_num_threads64_', 'openblas_get_num_threads64_', "
            "'openblas_get_num_threads'):\n"
            "    for lib in libs:\n"
            "        f = getattr(ctypes.CDLL(lib), name, None)\n"
            "        n = f() if f is not None and n < 0 else n\n"
            "print(os.environ['OPENBLAS_NUM_THREADS'], n)")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    var, threads = out.split()
    assert var == (user or "1"), out
    if int(threads) < 0:
        pytest.skip("numpy's BLAS says nothing of its threads (not OpenBLAS)")
    assert int(threads) == min(int(user or 1), os.cpu_count()), out  # OpenBLAS takes at most the cores
