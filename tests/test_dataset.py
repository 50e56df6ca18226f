"""bowsynth dataset: a corpus drawn from a spec, loaded back by Hugging Face datasets with no code of ours, resumed
after deletions and an interrupt, rendered the same on a real two-node Ray cluster with a worker killed mid-task,
and every bad spec or address refused in one line."""

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


def test_the_corpus_loads_with_datasets_and_its_labels_are_its_sound(corpus):
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
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120 and len(list((c / "data").glob("*.wav")) if (c / "data").is_dir() else []) < 20:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    rows = [json.loads(x) for x in (c / "metadata.jsonl").read_text().splitlines()]
    assert 20 <= len(rows) < 600
    for r in rows:
        assert sf.info(c / r["file_name"]).frames == 44100
    assert not [f for f in (c / "data").iterdir() if f.name.startswith(".")]  # no temporary file left
    p = bow("dataset", s, "--out", c, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert len((c / "metadata.jsonl").read_text().splitlines()) == 600


def test_a_ray_cluster_renders_the_same_corpus_with_a_worker_killed(corpus, tmp_path):
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    d, c = corpus
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    try:
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
    finally:
        cluster.shutdown()


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
