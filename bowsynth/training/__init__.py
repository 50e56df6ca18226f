"""Training the PI-DeepONet for one scene: config (the defaults), data (band, domain, FDM windows), losses (named
terms and their weighted sum), checkpoint, selection (weights chosen by rollout; validation), trainer (the loop).

Names are loaded on first use, so that `bowsynth.training.config` (no torch) can check settings before torch loads.
"""

import importlib

_WHERE = {
    "checkpoint_path": "config", "TrainConfig": "config", "NetConfig": "config",
    "GRID": "data", "StateSampler": "data", "fdm_windows": "data", "make_domain": "data", "scene_band": "data",
    "default_weights": "losses", "loss_terms": "losses", "residuals": "losses", "stiffness": "losses",
    "weighted": "losses", "validate": "selection", "TrainResult": "trainer", "Trainer": "trainer",
    "default_model_name": "config", "build_range": "data", "RangeSampler": "data", "validate_range": "selection",
    "RangeSelector": "selection", "ParamBox": "ranges", "parse_range": "ranges", "range_band": "ranges",
    "speaks": "ranges",
}

__all__ = sorted(_WHERE)


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(name)
