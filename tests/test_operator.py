import math

import numpy as np
import pytest
import torch
from conftest import tiny_config

from bowsynth import DomainError, ModelFileError, Scene, render_fdm
from bowsynth.metrics import nmse
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.network import DeepONet, NetConfig
from bowsynth.training import Trainer, default_weights, loss_terms


def _net():
    net = DeepONet(NetConfig(width=16, depth=2, k=8, ff_branch=8, ff_trunk=8), seed=1).double()
    net.set_scales([0.0, -0.05], [0.3, 0.3], [0.1, 0.2], 2 * math.pi)
    return net


def test_forward_mode_time_derivative_matches_finite_difference():
    net = _net()
    x0 = torch.randn(5, 2, dtype=torch.float64) * 0.2
    tau = torch.linspace(0.1, 6.0, 7, dtype=torch.float64)
    _, dx = net.forward_with_dt(x0, tau)
    h = 1e-6
    fd = (net(x0, tau + h) - net(x0, tau - h)) / (2 * h)
    assert torch.allclose(dx, fd, atol=1e-7, rtol=1e-6)


def test_hard_initial_condition_is_exact():
    net = _net()
    x0 = torch.randn(9, 2, dtype=torch.float64)
    x = net(x0, torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert torch.equal(x[:, 0], x0)


def test_linear_flow_is_exact_without_correction():
    net = _net()
    for p in net.parameters():
        torch.nn.init.zeros_(p)
    x0 = torch.tensor([[0.1, -0.2]], dtype=torch.float64)
    tau = torch.tensor([0.0, 0.5, 3.0], dtype=torch.float64)
    x = net(x0, tau)[0]
    assert torch.allclose(x[:, 0], 0.1 * torch.cos(tau) - 0.2 * torch.sin(tau))


def _window_error(model, sc):
    """Mean NMSE(p) of one-window predictions from states of the render from rest against an FDM x10."""
    from bowsynth.engines.operator.rollout import rollout_states

    path = render_fdm(sc.replace(duration=0.2))
    x0 = np.stack([path.q[::1300], path.p[::1300]], 1)
    n = int(round(2 * math.pi / (sc.omega / sc.sample_rate)))
    _, p, _ = rollout_states(model, x0, n, sc.omega / sc.sample_rate, check_domain=False)
    return np.mean([nmse(p[i], render_fdm(sc.replace(q0=q0, p0=p0, duration=n / sc.sample_rate), oversample=10).p)
                    for i, (q0, p0) in enumerate(x0)])


def _loss(tr, batch, sc) -> float:
    """The trainer's weighted loss on a batch, wherever its net is now: a run trains on its device (a GPU with device
    auto) and ends with the net on the CPU, where models render."""
    dev = next(tr.net.parameters()).device
    b = {k: v.to(dev) if torch.is_tensor(v) else v for k, v in batch.items()}
    return sum(tr.weights[k] * v for k, v in loss_terms(tr.net, b, sc, tr.weights).items()).item()


def test_tiny_training_lowers_loss_and_window_error():
    sc = Scene(fb=100)
    tr = Trainer(sc, tiny_config(steps=400), "t")
    batch = tr.batch()
    def loss():
        return _loss(tr, batch, sc)

    before, e_before = loss(), _window_error(tr.model(), sc)
    tr.run()
    after, e_after = loss(), _window_error(tr.model(), sc)
    assert after < 0.5 * before
    # measured 0.24 -> 0.16: 400 Adam steps of a 16-wide net; the untrained net is the frictionless flow R(tau) x0
    assert e_after < 0.8 * e_before


def test_same_seed_same_model():
    sc = Scene(fb=10)
    a, b = (Trainer(sc, tiny_config(steps=20), "t") for _ in range(2))
    a.run(), b.run()
    for (k, va), vb in zip(a.net.state_dict().items(), b.net.state_dict().values()):
        assert torch.equal(va, vb), k


def test_save_load_round_trip(tiny_model, tmp_path):
    """The net in memory before saving and the one loaded after give the same outputs and the same render."""
    m = load_model(tiny_model)
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():  # weights no file holds yet, as after more training
        for v in m.net.parameters():
            v.add_(0.05 * v.abs().mean() * torch.randn(v.shape, generator=g))
    x0 = torch.tensor([[0.01, 0.02], [0.1, -0.1], [-0.05, 0.2]])
    tau = torch.linspace(0, 6, 5)
    sc = Scene(fb=100, duration=0.05)
    with torch.no_grad():
        before = m.net(x0, tau)
        assert not torch.equal(before, load_model(tiny_model).net(x0, tau))  # the perturbation shows
    r_before = render_operator(sc, model=m)
    m.save(tmp_path / "s.safetensors")
    m2 = load_model(tmp_path / "s.safetensors")
    with torch.no_grad():
        assert torch.equal(m2.net(x0, tau), before)
    r_after = render_operator(sc, model=m2)
    np.testing.assert_array_equal(r_after.q, r_before.q)
    np.testing.assert_array_equal(r_after.p, r_before.p)
    d, d2 = m.domain, m2.domain
    assert np.array_equal(d.mask, d2.mask) and (d.q_lo, d.q_hi, d.p_lo, d.p_hi) == (d2.q_lo, d2.q_hi, d2.p_lo, d2.p_hi)
    assert m2.meta.scene == m.meta.scene and m2.id == m.id != load_model(tiny_model).id
    m = m2  # the checks below read the loaded model
    assert m.meta.domain.beta == pytest.approx(Scene(fb=100).beta)
    assert m.id.startswith("tiny@") and m.meta.format_version == 2 and m.meta.digest.startswith("sha256:")


def test_domain_check(tiny_model):
    m = load_model(tiny_model)
    assert m.covers(Scene(fb=100))
    assert m.covers(Scene(fb=300, f0=300))  # same F_B / w: one model serves every pitch
    assert not m.covers(Scene(fb=1000))
    assert not m.covers(Scene(fb=100, vb=0.3))
    assert not m.covers(Scene(fb=100, q0=5.0))
    why = m.domain.mismatch(Scene(fb=100, q0=5.0, a=50))
    assert any("initial state" in w for w in why) and any(w.startswith("a =") for w in why)
    with pytest.raises(DomainError, match="does not cover"):
        render_operator(Scene(fb=1000), model=m)


def test_corrupt_and_foreign_model_files(tmp_path, tiny_model):
    data = tiny_model.read_bytes()
    cases = {"truncated": data[: len(data) // 2], "random": np.random.default_rng(0).bytes(4096), "empty": b""}
    for name, blob in cases.items():
        p = tmp_path / f"{name}.safetensors"
        p.write_bytes(blob)
        with pytest.raises(ModelFileError):
            load_model(p)
    from safetensors.torch import save_file

    foreign = tmp_path / "foreign.safetensors"
    save_file({"w": torch.zeros(3)}, str(foreign))
    with pytest.raises(ModelFileError, match="not a bowsynth model"):
        load_model(foreign)
    with pytest.raises(ModelFileError, match="not found"):
        load_model(tmp_path / "missing.safetensors")


def test_wrong_shapes_and_version_rejected(tmp_path, tiny_model):
    import json

    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(tiny_model), framework="pt") as f:
        meta = json.loads(f.metadata()["bowsynth"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    from bowsynth.engines.operator.modelfile import digest

    bad = dict(tensors, **{"bias": torch.zeros(5)})
    save_file(bad, str(tmp_path / "shape.safetensors"), metadata={"bowsynth": json.dumps(meta)})
    with pytest.raises(ModelFileError, match="metadata does not match the weights"):
        load_model(tmp_path / "shape.safetensors")
    forged = {**meta, "digest": digest(meta, {k: v.numpy() for k, v in bad.items()})}  # past the digest
    save_file(bad, str(tmp_path / "shape.safetensors"), metadata={"bowsynth": json.dumps(forged)})
    with pytest.raises(ModelFileError, match="damaged"):
        load_model(tmp_path / "shape.safetensors")
    save_file(tensors, str(tmp_path / "v9.safetensors"), metadata={"bowsynth": json.dumps({**meta, "format_version": 9})})
    with pytest.raises(ModelFileError, match="format version 9"):
        load_model(tmp_path / "v9.safetensors")


def test_default_weights_drop_friction_residual_when_stiff():
    assert "fric" in default_weights(Scene(fb=100), hybrid=True)
    assert "fric" not in default_weights(Scene(fb=1000), hybrid=True)
    assert set(default_weights(Scene(fb=1000), hybrid=False)) == {"kin", "fric"}


def test_checkpoint_resume_continues_identically(tmp_path):
    sc = Scene(fb=100)
    full = Trainer(sc, tiny_config(steps=40), "t")
    full.run()

    class Stop(Exception):
        pass

    def stop_at_20(rec):
        if first.step == 20:
            raise Stop

    first = Trainer(sc, tiny_config(steps=40), "t")
    with pytest.raises(Stop):
        first.run(on_step=stop_at_20)
    ck = tmp_path / "c.ckpt.safetensors"
    first.save_checkpoint(ck)
    second = Trainer(sc, tiny_config(steps=40), "t")
    second.load_checkpoint(ck)
    assert second.step == 20
    second.run()
    assert second.step == 40
    for va, vb in zip(full.net.state_dict().values(), second.net.state_dict().values()):
        assert torch.allclose(va, vb, atol=1e-6)


def test_soap_steps_lower_the_loss():
    sc = Scene(fb=100)
    tr = Trainer(sc, tiny_config(steps=60, optimizer="soap", lr=3e-3), "t")
    batch = tr.batch()
    loss = lambda: _loss(tr, batch, sc)  # noqa: E731
    before = loss()
    tr.run()
    assert loss() < before


def test_selection_keeps_the_best_scored_weights(monkeypatch, tmp_path):
    sc = Scene(fb=100)
    tr = Trainer(sc, tiny_config(steps=12, select_every=1e-9, select_from=0.0), "t")
    scores = iter([5.0, 4.0, 0.5, 3.0, 2.0] + [9.0] * 20)  # the third scoring wins
    snaps = []

    def fake_score(model):
        snaps.append((tr.step, {k: v.clone() for k, v in tr.net.state_dict().items()}))
        return next(scores)

    monkeypatch.setattr(tr.selector, "score", fake_score)
    tr.run()
    step, best = snaps[2]
    assert tr.step == 12 and step < 12 and len(snaps) == 13  # every step, and the final weights
    for k, v in tr.net.state_dict().items():
        assert torch.equal(v.cpu(), best[k].cpu()), k  # the run ends with the net on the CPU, wherever it trained
    sel = tr.model().meta.training["selected"]
    assert (sel["step"], sel["scored"], sel["score_nmse_p"]) == (step, 13, 0.5)
    ck = tmp_path / "t.ckpt.safetensors"  # a checkpoint carries the best weights, for --resume
    tr.save_checkpoint(ck)
    tr2 = Trainer(sc, tiny_config(steps=12, select_every=1e-9, select_from=0.0), "t")
    tr2.load_checkpoint(ck)
    assert tr2.best["step"] == step and tr2.best["score"] == 0.5 and tr2.best["scored"] == 13
    assert all(torch.equal(tr2.best["state"][k].cpu(), v.cpu()) for k, v in best.items())


def test_selection_scores_a_rollout_from_a_state_the_validation_and_the_window_starts_never_use(tiny_model):
    from bowsynth import render_fdm, render_operator
    from bowsynth.metrics import nmse
    from bowsynth.training.data import window_starts

    tr = Trainer(Scene(fb=100), tiny_config(steps=1, sampling="box"), "t")  # the tiny model's own settings
    tr.net.load_state_dict(load_model(tiny_model).net.state_dict())
    model = tr.model()
    score = tr.selector.score(model)
    sel = tr.selector.scene
    assert (sel.q0, sel.p0) != (0.0, 0.0) and sel.f0 == 100.0 and sel.duration == 1.0
    starts = window_starts(tr.scene, tr.data.band, tr.window)
    assert np.min(np.hypot(starts[:, 0] - sel.q0, starts[:, 1] - sel.p0)) > 1e-3
    assert score == pytest.approx(nmse(render_operator(sel, model=model).p, render_fdm(sel, oversample=100).p))


def test_training_progress_in_a_pipe_is_plain_whole_lines_for_every_phase(tmp_path):
    import io

    from rich.console import Console

    from bowsynth import api

    buf = io.StringIO()
    console = Console(file=buf, width=80)  # not a terminal: plain lines
    api.train(Scene(fb=100), config=tiny_config(steps=60), out=tmp_path / "m.safetensors", progress=True,
              console=console)
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("train: preparing")
    text = "\n".join(lines)
    for phase in ("preparing: FDM data", "training: ", "validating"):
        assert phase in text, text
    assert all(line.startswith("train: ") for line in lines)


def test_reporter_heartbeat_prints_during_a_silent_phase():
    import io
    import time

    from rich.console import Console

    from bowsynth.io.progress import Reporter

    buf = io.StringIO()
    with Reporter(Console(file=buf), every=0.2) as rep:
        rep.update("a phase without callbacks", 0.5)
        time.sleep(1.5)  # the heartbeat wakes every second
    assert buf.getvalue().count("a phase without callbacks") >= 2


def test_reporter_lines_are_never_cut_at_the_console_width():
    import io

    from rich.console import Console

    from bowsynth.io.progress import Reporter

    buf = io.StringIO()
    info = "step 900 " + " ".join(f"term{i} 1.0e-03" for i in range(12))
    with Reporter(Console(file=buf, width=40)) as rep:
        rep.update("training", 0.5, info)
    assert buf.getvalue().splitlines() == [line for line in buf.getvalue().splitlines() if info in line]


def test_voices_of_very_different_lengths_roll_in_groups_and_each_is_its_own_render():
    """A score's notes differ in length: they roll in groups of similar length (rollout.length_buckets), and each
    voice is the same as its render alone."""
    from bowsynth.engines.operator.rollout import LENGTH_SLACK, length_buckets

    lengths = [100, 2000, 110, 114, 1000, 116, 2100, 100]
    groups = length_buckets(lengths)
    assert sorted(int(i) for g in groups for i in g) == list(range(len(lengths)))
    for g in groups:
        assert max(lengths[i] for i in g) <= LENGTH_SLACK * min(lengths[i] for i in g)
    assert len(groups) == 4  # 100-114, 116, 1000, 2000-2100
    from pathlib import Path

    import bowsynth

    model = load_model(bowsynth.shipped("models") / "paper-fb100.safetensors")
    scenes = [Scene(f0=f0, fb=f0, duration=d) for f0, d in ((100.0, 0.05), (220.0, 0.4), (150.0, 0.052))]
    together = render_operator(scenes, model=model)
    for sc, r in zip(scenes, together):
        alone = render_operator(sc, model=model)
        assert len(r.p) == sc.n_samples
        np.testing.assert_allclose(r.p, alone.p, rtol=0, atol=1e-6 * np.abs(alone.p).max())


def test_an_operator_render_makes_its_time_axis_when_it_is_read():
    # the engine passes no time axis (1 ms of fresh pages for 5 s, which few callers read); the render makes the
    # sample times on first use, and the controls of a moving bow are read at them
    sc = Scene(fb=[(0.0, 50.0), (0.3, 120.0)], duration=0.4)
    r = render_operator(sc)
    assert r.__dict__.get("_t") is None  # not made yet
    np.testing.assert_array_equal(r.t, np.arange(len(r.p)) / sc.sample_rate)
    assert r.t.dtype == np.float64 and r.t is r.t
    assert len(r.controls["fb"]) == len(r.p)
