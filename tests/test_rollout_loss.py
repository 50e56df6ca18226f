"""The rollout term (losses.rollout_term): chains of windows rolled out from the network's own end states against
the FDM's window boundaries, its data, and the setting's path through recipes and `train --update`."""

import dataclasses
import math

import numpy as np
import pytest
import torch
from conftest import run_main, tiny_config

from bowsynth import Scene
from bowsynth.engines.operator.network import DeepONet, NetConfig
from bowsynth.training import ParamBox
from bowsynth.training.losses import loss_terms, rollout_term


def _range_net():
    box = ParamBox(1.6, 1.7, 0.0708, 0.0712, 100.0)
    net = DeepONet(NetConfig(width=8, depth=1, k=4, ff_branch=4, ff_trunk=4, params=2, corr_beta=True), seed=3)
    net.set_box(box)
    net.set_scales([0.0, 0.0], [0.5, 0.5], np.array([0.05, 0.08]), 2 * math.pi)
    return net, box


def _states(n, seed):
    rng = np.random.default_rng(seed)
    x = torch.tensor(rng.normal(0, 0.2, (n, 2)), dtype=torch.float32)
    par = torch.tensor(np.c_[rng.uniform(1.6, 1.7, n), rng.uniform(0.0708, 0.0712, n)], dtype=torch.float32)
    return x, par


def test_a_chain_of_one_window_is_the_end_term_and_two_windows_start_the_second_from_the_first():
    net, _ = _range_net()
    x0, par = _states(6, 0)
    ends = torch.tensor(np.random.default_rng(1).normal(0, 0.2, (6, 2, 2)), dtype=torch.float32)
    tau = torch.linspace(0, 2 * math.pi, 5)
    data_x = torch.zeros(6, 5, 2)
    data_x[:, -1] = ends[:, 0]
    batch = {"data_x0": x0, "data_x": data_x, "data_tau": tau, "data_par": par, "phys_x0": x0, "phys_par": par,
             "phys_tau": tau, "chain_x": torch.stack([x0, ends[:, 0]], 1), "chain_par": par}
    terms = loss_terms(net, batch, Scene(), {"end": 1.0, "roll": 1.0})
    assert torch.allclose(terms["roll"], terms["end"], rtol=1e-5)
    # two windows: the second starts where the network ended the first, not at the FDM's boundary
    batch["chain_x"] = torch.stack([x0, ends[:, 0], ends[:, 1]], 1)
    with torch.no_grad():
        first = net(x0, tau[-1:], par)[:, -1]
        second = net(first, tau[-1:], par)[:, -1]
        scale = net.corr_scale * net.gain(par)[:, None]
        want = (((first - ends[:, 0]) / scale).square().mean() + ((second - ends[:, 1]) / scale).square().mean()) / 2
        assert torch.allclose(rollout_term(net, batch), want, rtol=1e-5)
        from_truth = net(ends[:, 0], tau[-1:], par)[:, -1]
        assert not torch.allclose(second, from_truth, atol=1e-4)  # so the test tells the two apart
    rollout_term(net, batch).backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in net.branch.parameters())


def test_the_chains_are_the_fdm_window_after_window_and_leave_the_other_data_as_it_was():
    from bowsynth.training.data import add_chains, build_range, fdm_windows

    box = ParamBox(1.6, 1.7, 0.0708, 0.0712, 100.0)
    scene = Scene(f0=100, fb=1.65 * 2 * math.pi * 100, vb=0.071)
    window = math.pi / 2
    plain_cfg = dataclasses.replace(tiny_config(range_points=4, range_gestures=1, range_stops=0, range_n_data=32),
                                    band_seconds=0.2, data_times=16, data_oversample=8)
    plain = build_range(scene, box, plain_cfg, window, np.random.default_rng(5))
    cfg = dataclasses.replace(plain_cfg, rollout=1.0, rollout_windows=3, rollout_chains=16, rollout_batch=4)
    data = add_chains(build_range(scene, box, cfg, window, np.random.default_rng(5)), scene, cfg, window)
    assert np.array_equal(plain.x0, data.x0) and np.array_equal(plain.x, data.x) and plain.chain_x is None
    assert data.chain_x.shape == (16, 4, 2) and data.chain_par.shape == (16, 2)
    assert box.contains(data.chain_par[:, 0], data.chain_par[:, 1]).all()
    # the chains start where renders go: band states, not jittered as the one-window data's starts are
    def gap(x):
        return np.abs(x[:, None] - data.band[None]).sum(-1).min(1)
    assert gap(data.chain_x[:, 0]).max() < 1e-9 and np.median(gap(data.x0)) > 1e-6
    span = np.ptp(data.chain_x[..., 1])
    for k in (1, 3):  # each boundary is one FDM window on from the one before (a finer step: a small difference)
        _, one = fdm_windows(scene, data.chain_x[:, k - 1], window, 16, 32, par=data.chain_par)
        assert np.max(np.abs(one[:, -1] - data.chain_x[:, k])) < 0.02 * span
    assert np.max(np.abs(data.chain_x[:, 3] - data.chain_x[:, 0])) > 0.1 * span  # the chain moves


def test_a_range_model_trains_with_the_rollout_term_and_records_it(tmp_path):
    from bowsynth import api
    from bowsynth.engines.operator.modelfile import load_model

    box = ParamBox(1.6, 1.7, 0.0708, 0.0712, 100.0)
    scene = api.range_scene(box, 100.0, 44100)
    cfg = tiny_config(steps=60, rollout=0.5, rollout_windows=2, rollout_chains=16, rollout_batch=4,
                      range_points=4, range_gestures=1, range_stops=0, range_n_data=64, window=math.pi / 2)
    r = api.train(scene, config=cfg, box=box, out=tmp_path / "m.safetensors")
    m = load_model(tmp_path / "m.safetensors")
    assert m.meta.training["weights"]["roll"] == 0.5 and m.meta.training["rollout"] == 0.5
    assert all(math.isfinite(h["roll"]) for h in r.history) and r.history


def test_a_recipe_names_its_rollout_weight_and_update_compares_it(tmp_path, capsys, monkeypatch):
    from bowsynth import api
    from bowsynth.cli.train import recipe_status

    api.train(Scene(fb=100), out=tmp_path / "m.safetensors", steps=2, batch_states=64, n_data=64,
              width=8, rollout=0.5, rollout_chains=16, rollout_batch=4, rollout_windows=2)
    rec = tmp_path / "r.toml"
    rec.write_text('fb = 100\nsteps = 2\nbatch = 64\nwidth = 8\nrollout = 0.5\nout = "m.safetensors"\n')
    assert recipe_status(rec) is None
    rec.write_text(rec.read_text().replace("rollout = 0.5", "rollout = 0"))
    assert "stale: trained with rollout 0.5, the recipe asks for 0" in recipe_status(rec)
    rec.write_text(rec.read_text().replace("rollout = 0", 'rollout = "lots"'))
    code, out, err = run_main(["train", "--config", str(rec)], capsys, monkeypatch)
    assert code == 2 and "rollout must be int or float" in err and "Traceback" not in err, err
    for bad in ("-0.1", "101", "nan"):
        code, out, err = run_main(["train", "--fb", "100", "--steps", "1", "--rollout", bad], capsys, monkeypatch)
        assert code == 2 and "--rollout must be in [0, 100]" in err and "Traceback" not in err, err


@pytest.mark.parametrize("windows, chains, batch", [(0, 16, 4), (2, 8, 4), (2, 16, 17), (257, 16, 4)])
def test_chain_settings_that_cannot_train_are_refused_in_one_line(windows, chains, batch):
    from bowsynth.errors import UsageError
    from bowsynth.training import TrainConfig

    with pytest.raises(UsageError, match="rollout chains"):
        TrainConfig(rollout=1.0, rollout_windows=windows, rollout_chains=chains, rollout_batch=batch).validate()
