"""compare tells the truth first: the x100 FDM is the default reference; gestures are compared with their own curves."""

import json

from conftest import run_main


def test_default_reference_is_the_high_rate_fdm_with_the_audio_rate_beside(tmp_path, capsys, monkeypatch):
    out = tmp_path / "a4.wav"
    code, _, err = run_main(["render", str(out), "--preset", "violin-a4", "-d", "0.5"], capsys, monkeypatch)
    assert code == 0, err
    code, so, err = run_main(["compare", str(out), "--json"], capsys, monkeypatch)
    assert code == 0, err
    m = json.loads(so)["metrics"]
    labels = list(m)
    assert labels[0] == "file vs FDM x100 (truth)" and labels[1] == "file vs FDM"
    # at A4 the operator is closer to the truth than the audio-rate FDM is (issue 11: NCC 89 % against the latter)
    assert m[labels[0]]["nmse"] < m["FDM vs FDM x100"]["nmse"]
    code, so, err = run_main(["compare", str(out), "--json", "--reference", "audio"], capsys, monkeypatch)
    assert list(json.loads(so)["metrics"]) == ["file vs FDM"]


def test_a_gesture_is_compared_with_the_fdm_of_the_same_curves(tmp_path, capsys, monkeypatch):
    out = tmp_path / "cresc.wav"
    code, _, err = run_main(["render", str(out), "--method", "fdm", "--fb", "50@0,200@0.3", "--vb", "0.2@0,0.1@0.4",
                             "-d", "0.4"], capsys, monkeypatch)
    assert code == 0, err
    code, so, err = run_main(["compare", str(out), "--json"], capsys, monkeypatch)
    assert code == 0, err
    js = json.loads(so)
    assert js["scene"]["fb"] == [[0.0, 50.0], [0.3, 200.0]] and js["scene"]["vb"] == [[0.0, 0.2], [0.4, 0.1]]
    # the file is the audio-rate FDM of those curves: against it, only float32 storage differs
    assert js["metrics"]["file vs FDM"]["nmse"] < 1e-12
    # while a render of the held bow differs at once
    flat = tmp_path / "flat.wav"
    run_main(["render", str(flat), "--method", "fdm", "--fb", "50", "-d", "0.4"], capsys, monkeypatch)
    code, so, err = run_main(["compare", str(out), str(flat), "--json"], capsys, monkeypatch)
    assert list(json.loads(so)["metrics"].values())[0]["nmse"] > 1e-3
