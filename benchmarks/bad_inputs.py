"""Run each bad input through the real CLI and print a Markdown table of the message and exit code it gets.

    .venv/bin/python benchmarks/bad_inputs.py > docs/bad_inputs.md
"""

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import soundfile as sf

CASES = [
    ("non-finite physics", "render --method fdm --fb nan x.wav"),
    ("negative bow force", "render --method fdm --fb -5 x.wav"),
    ("pitch above Nyquist", "render --method fdm --f0 30000 x.wav"),
    ("sample rate out of range", "render --method fdm --sr 1000 x.wav"),
    ("zero duration", "render --method fdm --duration 0 x.wav"),
    ("not a number", "render --method fdm --fb abc x.wav"),
    ("unknown preset", "render --preset viola x.wav"),
    ("unknown option", "render --bogus 1 x.wav"),
    ("output directory missing", "render --method fdm nodir/x.wav"),
    ("scene no model covers", "render --fb 123 --vb 0.3 x.wav"),
    ("missing model file", "render --model nomodel.safetensors x.wav"),
    ("corrupt model file", "render --model garbage.safetensors x.wav"),
    ("model of another format version", "render --model v9.safetensors x.wav"),
    ("missing WAV", "compare nofile.wav"),
    ("not an audio file", "compare garbage.wav"),
    ("WAV without bowsynth metadata", "compare plain.wav"),
    ("plot to a non-PNG name", "compare ok.wav --plot p.jpg"),
    ("existing model without --force", "train --fb 100 --steps 5 --out exists.safetensors"),
    ("resume without a checkpoint", "train --fb 100 --resume --out new.safetensors"),
    ("zero training budget", "train --fb 100 --minutes 0"),
    ("unknown optimiser", "train --fb 100 --optimizer sgd --steps 1 --out n.safetensors"),
    ("score file that is not TOML", "score --score bad.toml outdir"),
    ("unknown fallback for a score", "score --presets paper-fb100 --fallback maybe outdir"),
    ("anchors directory missing", "bench --anchors no_such_dir"),
    ("FDM past its uniqueness bound", "render --method fdm --fb 10000 -d 0.05 ok2.wav"),
    ("a scene that would need absurd oversampling", "render --method fdm --fb 1e6 --a 1e6 x.wav"),
]


def main():
    exe = [sys.executable, "-m", "bowsynth"]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        (d / "garbage.safetensors").write_bytes(b"\x00garbage" * 10)
        (d / "garbage.wav").write_bytes(b"RIFF0000WAVEjunk" * 4)
        (d / "bad.toml").write_text("[[voice]\nfb = ")
        (d / "exists.safetensors").write_bytes(b"x")
        sf.write(d / "plain.wav", np.zeros(100), 44100)
        subprocess.run(exe + ["render", "--method", "fdm", "-d", "0.1", "ok.wav"], cwd=d, check=True,
                       capture_output=True)
        import json

        import torch
        from safetensors.torch import save_file

        save_file({"w": torch.zeros(1)}, str(d / "v9.safetensors"),
                  metadata={"bowsynth": json.dumps({"format": "bowsynth-operator", "format_version": 9})})
        print("| bad input | command | exit code | what bowsynth says |")
        print("|---|---|---|---|")
        for what, cmd in CASES:
            r = subprocess.run(exe + cmd.split(), cwd=d, capture_output=True, text=True, env={"COLUMNS": "400",
                               "PATH": "/usr/bin:/bin", "HOME": str(d)})
            msg = " / ".join(line for line in r.stderr.strip().splitlines() if line.strip()) or "(nothing)"
            msg = msg.replace(str(d) + "/", "").replace("|", "\\|")
            print(f"| {what} | `bowsynth {cmd}` | {r.returncode} | {msg} |")


if __name__ == "__main__":
    main()
