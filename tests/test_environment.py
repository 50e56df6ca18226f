"""Odd environments: a cache entry that is a FIFO or damaged, two processes at once, a user with no home
directory."""

import json
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


def test_a_cache_entry_that_is_a_fifo_is_ignored_not_waited_on(tmp_path):
    d = tmp_path / "cache"
    cmd = [sys.executable, "-m", "bowsynth", "render", "--pitch", "A3", "--method", "fdm", "-d", "0.1"]
    first = subprocess.run(cmd + [str(tmp_path / "a.wav")], env=_env(BOWSYNTH_CACHE=str(d)), capture_output=True,
                           text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    entries = list(d.rglob("*.json"))
    assert entries
    for e in entries:  # every entry the first process kept is now a FIFO: reading one would wait forever
        e.unlink()
        os.mkfifo(e)
    r = subprocess.run(cmd + [str(tmp_path / "b.wav")], env=_env(BOWSYNTH_CACHE=str(d)), capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "f0 224.3" in r.stdout and (tmp_path / "b.wav").stat().st_size > 0
    assert all(e.is_file() for e in entries)  # measured again and written over the FIFOs


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


@pytest.mark.parametrize("junk", [b"[" * 100000, b"\xff\xfe not utf-8", b'{"version": 1}', b"x" * (2 << 20)])
def test_a_damaged_cache_entry_is_ignored(tmp_path, monkeypatch, junk):
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    cache.DiskTable("t", "v1").put("k", 0)
    cache.DiskTable("t", "v1").entry_path("k").write_bytes(junk)
    t = cache.DiskTable("t", "v1")
    assert t.get("k") is None
    t.put("k", 1)
    assert cache.DiskTable("t", "v1").get("k") == 1


def test_a_file_where_a_table_would_be_is_left_alone(tmp_path, monkeypatch):
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    (tmp_path / "t").write_text("mine")
    os.mkfifo(tmp_path / "u")
    for name in ("t", "u"):
        cache.DiskTable(name, "v1").put("k", 1)  # no error, nothing written
        assert cache.DiskTable(name, "v1").get("k") is None
    assert (tmp_path / "t").read_text() == "mine" and sorted(os.listdir(tmp_path)) == ["t", "u"]


def test_two_processes_at_once_keep_what_each_wrote(tmp_path, monkeypatch):
    """Each process reads the table before the other writes (with a table in one file, the last process to write it
    would drop the other's new entries, measured again by every later process: seconds each)."""
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    cache.DiskTable("t", "v1").put("old", 0)
    a, b = cache.DiskTable("t", "v1"), cache.DiskTable("t", "v1")
    assert a.get("old") == 0 and b.get("old") == 0
    a.put("a", 1)
    b.put("b", 2)
    later = cache.DiskTable("t", "v1")
    assert (later.get("old"), later.get("a"), later.get("b")) == (0, 1, 2)
    assert cache.DiskTable("t", "v2").get("a") is None  # another version of the measurement: not an answer


def test_a_table_keeps_its_newest_entries_and_versions(tmp_path, monkeypatch):
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    monkeypatch.setattr(cache, "MAX_ENTRIES", 10)
    (tmp_path / "t.json").write_text('{"version": "v0", "entries": {}}')  # the one-file table of an older bowsynth
    for i, v in enumerate(("v1", "v2")):
        cache.DiskTable("t", v).put("k", v)
        os.utime(cache.DiskTable("t", v).entry_path("k").parent, ns=(i * 10**9, i * 10**9))
    t = cache.DiskTable("t", "v3")
    for i in range(12):
        t.put(f"k{i}", i)
        os.utime(t.entry_path(f"k{i}"), ns=(i * 10**9, i * 10**9))  # written a second apart, whatever the clock
    t.put("k12", 12)
    left = {json.loads(p.read_text())["key"] for p in (tmp_path / "t").rglob("*.json")}
    assert "k12" in left and "k11" in left and "k0" not in left and len(left) <= 10
    assert [cache.DiskTable("t", v).get("k") for v in ("v1", "v2")] == [None, "v2"]  # the newest other version kept
    assert not (tmp_path / "t.json").exists()


def test_cached_arrays_keep_the_most_recently_used_within_their_bound(tmp_path, monkeypatch):
    """The trunk arrays (8 MB a model) are bounded, the least recently used (read or written) removed first; links and
    a killed writer's fresh temporary file stay, an old one goes."""
    import numpy as np

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    a = np.arange(1000.0)
    monkeypatch.setattr(cache, "MAX_ARRAYS_TOTAL", 3 * (a.nbytes + 200))  # three arrays and their headers
    outside = tmp_path.parent / "elsewhere.npy"
    np.save(outside, a)
    (tmp_path / "link.npy").symlink_to(outside)
    for i, name in enumerate(("trunk-old", "trunk-used", "trunk-mid")):
        cache.write_array(name, a + i)
        os.utime(tmp_path / f"{name}.npy", ns=(i * 10**9, i * 10**9))
    for name, age in ((".x.npy.0001abcd.tmp", 7200), (".y.npy.0002abcd.tmp", 10)):
        (tmp_path / name).write_bytes(b"half")
        t = os.stat(tmp_path / name).st_mtime - age
        os.utime(tmp_path / name, (t, t))
    assert cache.read_array("trunk-used", a.shape)[1] == 2.0  # reading it marks it used: now the newest of the three
    cache.write_array("trunk-new", a + 3)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [".y.npy.0002abcd.tmp", "link.npy", "trunk-mid.npy", "trunk-new.npy", "trunk-used.npy"]
    assert outside.exists() and cache.read_array("trunk-new", a.shape)[0] == 3.0


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


def test_the_cache_follows_no_link_and_removes_only_what_it_wrote(tmp_path, monkeypatch):
    """A cache table whose directory is a symlink to a user's directory: a render neither writes into it nor prunes
    through it, and the user's files, named or not like the cache's, stay. Foreign files in the cache's own
    directories (a user's .npy, a .tmp, a .json of another name) stay through pruning too."""
    import numpy as np

    from bowsynth.io import cache

    root = tmp_path / "cache"
    user = tmp_path / "user"
    (user / "photos").mkdir(parents=True)
    (user / "photos" / "a.jpg").write_bytes(b"x")
    (user / "0123456789abcdef01234567").mkdir()  # named like a version directory
    (user / "notes.json").write_text("{}")
    root.mkdir()
    (root / "sounding-ratio").symlink_to(user, target_is_directory=True)
    (root / "mine.npy").write_bytes(b"not ours")
    (root / ".x.tmp").write_bytes(b"not ours")
    monkeypatch.setenv("BOWSYNTH_CACHE", str(root))
    t = cache.DiskTable("sounding-ratio", "v1")
    t.put("k", {"r": 0.5})
    assert cache.DiskTable("sounding-ratio", "v1").get("k") is None  # never written through the link
    before = sorted(p.relative_to(user) for p in user.rglob("*"))
    for v in ("v2", "v3", "v4"):
        cache.DiskTable("sounding-ratio", v).put("k", 1.0)
    assert sorted(p.relative_to(user) for p in user.rglob("*")) == before
    cache.write_array("trunk-test", np.zeros(3))
    cache._prune_arrays(root, "none")  # every array over no budget: only the cache's own go
    monkeypatch.setattr(cache, "MAX_ARRAYS_TOTAL", 0)
    cache._prune_arrays(root, "none")
    assert (root / "mine.npy").exists() and (root / ".x.tmp").exists() and not (root / "trunk-test.npy").exists()
