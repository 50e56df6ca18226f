"""A deliberately worse copy of a shipped model, to show that tests/test_accuracy.py catches a 10x regression.

    PYTHONPATH=. .venv/bin/python benchmarks/worse_model.py paper-fb100 0.0035 /tmp/worse/paper-fb100.safetensors
    cp models/paper-fb10.safetensors models/paper-fb1000.safetensors /tmp/worse/
    BOWSYNTH_TEST_MODELS=/tmp/worse .venv/bin/python -m pytest tests/test_accuracy.py   # fails for paper-fb100

Adds Gaussian noise of `sigma` times each tensor's mean magnitude to every weight (seed 0) and prints the copy's
in-sample NMSE(p) over 0.25 s (measured: sigma 0.0035 gives 3.0e-5 against the shipped 2.6e-6).
"""

import sys

import torch

from bowsynth import Scene, load_model, render_fdm, render_operator
from bowsynth.metrics import nmse
from bowsynth.engines.operator.choose import SHIPPED_DIR

name, sigma, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
m = load_model(SHIPPED_DIR / f"{name}.safetensors")
g = torch.Generator().manual_seed(0)
with torch.no_grad():
    for v in m.net.parameters():
        v.add_(torch.randn(v.shape, generator=g) * sigma * v.abs().mean())
m.save(out, force=True)
sc = Scene(**{**m.meta.scene, "duration": 0.25})  # the model's training scene (a range model: its box's centre)
print(f"{name}, sigma {sigma:g}: in-sample NMSE(p) 0.25 s",
      f"{nmse(render_operator(sc, model=load_model(out)).p, render_fdm(sc, oversample=100).p):.2e}")
