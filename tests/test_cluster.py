"""The independent work, in one process and on a real two-node Ray cluster: bowsynth dataset (a corpus drawn from a
spec, loaded back by Hugging Face datasets with no code of ours, resumed after deletions and an interrupt, rendered
the same on the cluster with a worker killed mid-task, every bad spec or address refused in one line), the pitch
map's build as tasks, and train --atlas (two tiny units on the cluster, one worker killed mid-unit)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf


def bow(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "bowsynth", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600, env=env)


def one_line(p):
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    return lines[0]


def spec(tmp_path, name="spec.toml", **kw):
    d = {"count": 50, "seed": 4, "duration": 0.4, "gestures": 0.3} | kw
    text = "\n".join(f"{k} = {json.dumps(v)}" for k, v in d.items())
    (tmp_path / name).write_text(text + "\n")
    return tmp_path / name


def samples(path):
    return sf.read(path, dtype="float32")[0]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    d = tmp_path_factory.mktemp("corpus")
    s = spec(d)
    p = bow("dataset", s, "--out", d / "c", cwd=d)
    assert p.returncode == 0, p.stderr
    return d, d / "c"


def test_the_corpus_loads_with_datasets_and_its_labels_are_its_sound(corpus, monkeypatch):
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")  # the audiofolder builder ships with datasets: no network asked
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    datasets = pytest.importorskip("datasets")
    pytest.importorskip("librosa")  # datasets' audio decoding
    from bowsynth import api
    from bowsynth.scene import Scene

    _, c = corpus
    ds = datasets.load_dataset("audiofolder", data_dir=str(c), split="train",
                               cache_dir=str(c.parent / "hf-cache"))
    assert ds.num_rows == 50
    assert {"audio", "kind", "f0", "fb", "vb", "engine", "model", "accuracy"} <= set(ds.column_names)
    kinds = set(ds["kind"])
    assert "held" in kinds and kinds & {"crescendo", "speed", "stop"}
    assert set(ds["engine"]) <= {"operator", "operator+fdm"} and ds["engine"].count("operator") >= 45
    for i in (0, 17, 49):
        row = ds[i]
        sc = Scene(f0=row["f0"], fb=json.loads(row["fb"]), vb=json.loads(row["vb"]), duration=row["duration"],
                   sample_rate=row["sample_rate"])
        from bowsynth.io.audio import wav_payload

        again = wav_payload(api.render(sc))[0]
        assert row["audio"]["sampling_rate"] == sc.sample_rate
        # alone or in a batch of 16 the rollout differs in float32 rounding only
        assert np.max(np.abs(np.asarray(row["audio"]["array"], np.float32) - again)) < 1e-5


def test_a_rerun_renders_only_what_is_missing(corpus, tmp_path):
    d, c = corpus
    import shutil

    c2 = tmp_path / "c"
    shutil.copytree(c, c2)
    before = {f.name: samples(f) for f in (c2 / "data").glob("*.wav")}
    for name in ("0000003.wav", "0000030.wav", "0000044.wav"):
        (c2 / "data" / name).unlink()
    cut = c2 / "data" / "0000010.wav"
    cut.write_bytes(cut.read_bytes()[:5000])  # a file cut short: not whole, rendered again
    p = bow("dataset", d / "spec.toml", "--out", c2, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "4 rendered now, 46 already there" in p.stdout
    again = {"0000003.wav", "0000030.wav", "0000044.wav", "0000010.wav"}
    for f in (c2 / "data").glob("*.wav"):
        if f.name in again:  # in a batch of other notes: the rollout's float32 rounding may differ
            assert np.max(np.abs(samples(f) - before[f.name])) < 1e-5
        else:  # untouched
            assert np.array_equal(samples(f), before[f.name])
    assert len((c2 / "metadata.jsonl").read_text().splitlines()) == 50


def test_an_interrupted_corpus_lists_only_whole_files_and_finishes(tmp_path):
    s = spec(tmp_path, count=600, duration=1.0, gestures=0.0)
    c = tmp_path / "c"
    proc = subprocess.Popen([sys.executable, "-m", "bowsynth", "dataset", str(s), "--out", str(c)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    meta = c / "metadata.jsonl"

    def listed():
        try:
            return len(meta.read_text().splitlines())
        except OSError:
            return 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120 and listed() < 16:  # a batch listed: the run is under way
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    rows = [json.loads(x) for x in (c / "metadata.jsonl").read_text().splitlines()]
    assert 16 <= len(rows) < 600
    for r in rows:
        assert sf.info(c / r["file_name"]).frames == 44100
    assert not [f for f in (c / "data").iterdir() if f.name.startswith(".")]  # no temporary file left
    p = bow("dataset", s, "--out", c, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert len((c / "metadata.jsonl").read_text().splitlines()) == 600


@pytest.fixture(scope="module")
def cluster():
    """A real Ray cluster of two nodes on this machine (a head and a worker node, one CPU each)."""
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    c.add_node(num_cpus=1)
    c.wait_for_nodes()
    yield c
    c.shutdown()


def test_a_table_builds_the_same_on_the_cluster(cluster, tmp_path):
    """The pitch map's build (ratio solves, the reference at build time) as Ray tasks equals the one process's."""
    from bowsynth.music import ratio_map

    on = ratio_map.build(tmp_path / "ray.npz", n=(3, 4), address=cluster.address)
    here = ratio_map.build(tmp_path / "one.npz", n=(3, 4), workers=1)
    with np.load(on) as a, np.load(here) as b:
        assert set(a.files) == set(b.files)
        for k in a.files:
            assert np.array_equal(a[k], b[k], equal_nan=True), k
        assert np.isfinite(a["r"]).sum() >= 4


def test_a_ray_cluster_renders_the_same_corpus_with_a_worker_killed(corpus, cluster, tmp_path):
    d, c = corpus
    env = dict(os.environ, RAY_ADDRESS=cluster.address)
    s = spec(tmp_path, count=50, seed=4, duration=0.4, gestures=0.3)
    killer = subprocess.Popen([sys.executable, "-c", KILL_ONE], stdout=subprocess.PIPE, text=True)
    p = bow("dataset", s, "--out", tmp_path / "r", cwd=tmp_path, env=env)
    killed = killer.communicate(timeout=60)[0].strip()
    assert p.returncode == 0, p.stderr
    assert "50 of 50 notes" in p.stdout
    for f in (c / "data").glob("*.wav"):
        assert np.array_equal(samples(f), samples(tmp_path / "r" / "data" / f.name)), f.name
    mine = [json.loads(x) for x in (c / "metadata.jsonl").read_text().splitlines()]
    theirs = [json.loads(x) for x in (tmp_path / "r" / "metadata.jsonl").read_text().splitlines()]
    assert mine == theirs
    assert killed.startswith("killed"), killed  # a worker died mid-task and its task ran again


def test_an_atlas_trains_on_the_cluster_with_a_worker_killed(cluster, tmp_path):
    """Two independent tiny units as Ray tasks, a worker killed mid-unit: both train (the killed one again, from its
    checkpoint or its start), the one of seed 1 has the weights one process gives it, and a second run finds both up
    to date."""
    from safetensors.numpy import load_file

    for name, seed, fb in (("a", 1, "80:120"), ("b", 2, "90:110")):
        (tmp_path / f"{name}.toml").write_text(
            f'f0 = 100\nfb = "{fb}"\nvb = "0.18:0.22"\nsteps = 30\nwidth = 16\nbatch = 64\nband_seconds = 0.3\n'
            f'seed = {seed}\nout = "{name}.safetensors"\n')
    env = dict(os.environ, RAY_ADDRESS=cluster.address)
    killer = subprocess.Popen([sys.executable, "-c", KILL_ONE.replace("_render_batch", "_unit")],
                              stdout=subprocess.PIPE, text=True)
    p = bow("train", "--atlas", tmp_path, cwd=tmp_path, env=env)
    killed = killer.communicate(timeout=60)[0].strip()
    assert p.returncode == 0, p.stdout + p.stderr
    assert "2 of 2 units trained or up to date" in p.stdout
    assert killed.startswith("killed"), killed
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "a.toml").write_text((tmp_path / "a.toml").read_text())
    q = bow("train", "--config", alone / "a.toml", "--quiet", cwd=alone)
    assert q.returncode == 0, q.stderr
    mine, theirs = load_file(str(tmp_path / "a.safetensors")), load_file(str(alone / "a.safetensors"))
    assert mine.keys() == theirs.keys() and all(np.array_equal(mine[k], theirs[k]) for k in mine)
    again = bow("train", "--atlas", tmp_path, cwd=tmp_path, env=env)
    assert again.returncode == 0 and again.stdout.count("up to date") >= 2, again.stdout


# kills the first Ray worker seen running a corpus task (its process title names the task)
KILL_ONE = """
import os, signal, time, subprocess
t0 = time.time()
while time.time() - t0 < 50:
    ps = subprocess.run(["ps", "-eo", "pid=,args="], capture_output=True, text=True).stdout.splitlines()
    busy = [line.split(None, 1)[0] for line in ps if line.split(None, 1)[1:] == ["ray::_render_batch"]]
    if busy:
        os.kill(int(busy[0]), signal.SIGKILL)
        print("killed", busy[0])
        break
    time.sleep(0.02)
else:
    print("none seen")
"""


def test_no_cluster_at_the_address_is_one_line(tmp_path):
    pytest.importorskip("ray")
    s = spec(tmp_path)
    p = bow("dataset", s, "--out", tmp_path / "c", "--address", "127.0.0.1:9", cwd=tmp_path)
    assert p.returncode == 1
    assert "no Ray cluster at 127.0.0.1:9" in one_line(p)
    assert not (tmp_path / "c" / "data").exists() or not list((tmp_path / "c" / "data").iterdir())


@pytest.mark.parametrize("body, words", [
    ("count = 5\ncolour = 3\n", "unknown key"), ("beta = [1.0, 0.5]\n", "empty range"),
    ("count = 10000000\nduration = 60.0\n", "GB"), ("count = 1.5\n", "whole number"), ("count = [\n", "not valid TOML"),
])
def test_bad_specs_one_line(tmp_path, body, words):
    (tmp_path / "s.toml").write_text(body)
    p = bow("dataset", tmp_path / "s.toml", "--out", tmp_path / "c", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert words in one_line(p)
    assert not (tmp_path / "c" / "metadata.jsonl").exists()


def test_the_atlas_eta_follows_the_pace_of_the_units_done():
    """Units done at half their budgets: the units left take half theirs, spread over the workers, and never less
    than the longest one left; nothing to say before a unit finishes, nothing left at the end."""
    from bowsynth.training.atlas import eta_seconds

    done = [{"seconds": 300.0, "minutes": 10.0}, {"seconds": 0.0, "minutes": None}]  # the second: skipped
    assert eta_seconds(done, [10.0, 10.0, 20.0], workers=1) == pytest.approx(0.5 * 60 * 40)
    assert eta_seconds(done, [10.0, 10.0, 20.0], workers=2) == pytest.approx(0.5 * 60 * 20)
    assert eta_seconds(done, [10.0, 10.0, 20.0], workers=8) == pytest.approx(0.5 * 60 * 20)  # the 20-minute unit
    assert eta_seconds([], [10.0], workers=2) is None
    assert eta_seconds(done, [], workers=2) == 0.0


def test_a_bench_map_on_the_cluster_is_the_map_of_one_process(cluster, tmp_path):
    """`bench map`'s cells as tasks on the two-node cluster come back in the grid's order, each the cell one process
    measures (the render's own time apart)."""
    import json

    args = ("bench", "map", "--grid", "2x2", "--f0", "220", "--seconds", "0.3", "--json")
    alone = bow(*args, cwd=tmp_path)
    spread = bow(*args, "--workers", "2", "--address", cluster.address, cwd=tmp_path)
    assert alone.returncode == 0 and spread.returncode == 0, alone.stderr + spread.stderr
    a, b = json.loads(alone.stdout)["cells"], json.loads(spread.stdout)["cells"]
    strip = [{k: v for k, v in c.items() if k != "op_seconds"} for c in a]
    assert len(a) == 4 and strip == [{k: v for k, v in c.items() if k != "op_seconds"} for c in b]
    assert {c["status"] for c in a} <= {"played", "silent", "not played"} and any(c["status"] == "played" for c in a)


def test_a_bench_equal_on_the_cluster_measures_what_one_process_does(cluster, tmp_path):
    """`bench equal`'s models as tasks on the two-node cluster: the rows in the models' order, each model's accuracy
    and the FDM it matches those of one process (the times apart: each task times its own renders)."""
    import json

    def accuracy_only(row):
        row = {k: v for k, v in row.items() if k != "ratio"}
        row["operator"] = {k: v for k, v in row["operator"].items() if k not in ("sec_per_audio_s", "gmac_per_s")}
        row["fdm"] = [{k: v for k, v in e.items() if k != "sec_per_audio_s"} for e in row["fdm"]]
        return row

    args = ("bench", "equal", "--quick", "--model", "paper-fb10,paper-fb100", "--json")
    alone = bow(*args, cwd=tmp_path)
    spread = bow(*args, "--workers", "2", "--address", cluster.address, cwd=tmp_path)
    assert alone.returncode == 0 and spread.returncode == 0, alone.stderr + spread.stderr
    a, b = (json.loads(p.stdout)["equal_accuracy"] for p in (alone, spread))
    assert [r["model"] for r in a] == [r["model"] for r in b] == ["paper-fb10", "paper-fb100"]
    assert [accuracy_only(r) for r in a] == [accuracy_only(r) for r in b]
    assert all(r["fdm"] and "harm_db" in r["operator"] for r in a)
    bad = bow("bench", "equal", "--quick", "--model", "paper-fb10,no-such-model", cwd=tmp_path)
    assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1 and "no-such-model" in bad.stderr
