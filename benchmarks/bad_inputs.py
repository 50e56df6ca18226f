"""Run each bad input through the real CLI and print a Markdown table of the message and exit code it gets.

    .venv/bin/python benchmarks/bad_inputs.py > docs/bad_inputs.md

It covers special output paths, truncated and edited files, extreme numbers, and signals sent to real processes
in several phases (the exit time after the signal is measured on a shared 2-core machine).
"""

import os
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
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
    ("scene no model covers", "render --fb 123 --vb 0.4 x.wav"),
    # ranges and gestures
    ("a bow range written high:low", "train --fb 200:50 --steps 1 --out r.safetensors"),
    ("a range with three parts", "train --fb 50:100:200 --steps 1 --out r.safetensors"),
    ("a curve given to train", "train --fb 50@0,100@1 --steps 1 --out r.safetensors"),
    ("--rest-linear for a range model", "train --fb 50:200 --rest-linear --steps 1 --out r.safetensors"),
    ("--rest-linear where the bow drives the mass hard", "train --fb 1000 --rest-linear --steps 1 --out r.safetensors"),
    ("--from a point model", "train --fb 100 --from paper-fb100 --steps 1 --out r.safetensors"),
    ("--from a range model that does not hold the bows", "train --fb 300:400 --from soft-range --steps 1 --out r.safetensors"),
    ("--from a model that does not exist", "train --fb 100 --from no-such-model --steps 1 --out r.safetensors"),
    ("--update with no recipe", "train --fb 100 --update --steps 1 --out r.safetensors"),
    ("--model a name no model has", "render --fb 100 --model no-such-model x.wav"),
    ("curve times not increasing", "render --fb 50@1,100@0 x.wav"),
    ("a non-finite curve value", "render --fb nan@0,100@1 x.wav"),
    ("a bow curve that leaves every model's range", "render --fb 100@0,3000@1 x.wav"),
    ("... the same with --fallback fdm (finishes with the FDM)", "render --fb 100@0,3000@1 -d 1 --fallback fdm x.wav"),
    ("a note whose model stays silent where the bow drives the mass (stick-high at F_B / w 2, v_B 0.28: the space's "
     "corner, which stick-top plays)", "render --f0 110 --fb 1382.3 --vb 0.28 -d 1 --model stick-high x.wav"),
    ("a curve on a parameter that cannot vary", "render --f0 100@0,200@1 x.wav"),
    ("missing model file", "render --model nomodel.safetensors x.wav"),
    ("corrupt model file", "render --model garbage.safetensors x.wav"),
    ("model of another format version", "render --model v9.safetensors x.wav"),
    ("missing WAV", "compare nofile.wav"),
    ("not an audio file", "compare garbage.wav"),
    ("WAV without bowsynth metadata", "compare plain.wav"),
    ("plot to a non-PNG name", "compare ok.wav --plot p.jpg"),
    ("existing model without --force", "train --fb 100 --steps 5 --out exists.safetensors"),
    ("resume without a checkpoint", "train --fb 100 --resume --out new.safetensors"),
    ("an unfinished run's checkpoint, the same command again without --resume",
     "train --fb 100 --steps 5 --out unfinished.safetensors"),
    ("zero training budget", "train --fb 100 --minutes 0"),
    ("unknown optimiser", "train --fb 100 --optimizer sgd --steps 1 --out n.safetensors"),
    ("score file that is not TOML", "score --score bad.toml outdir"),
    ("unknown fallback for a score", "score --presets paper-fb100 --fallback maybe outdir"),
    ("anchors directory missing", "bench --anchors no_such_dir"),
    ("a bench target that does not exist", "bench gpu"),
    ("an error map's grid that is not CELLSxCELLS", "bench map --grid 10by8"),
    ("an error map's pitch out of range", "bench map --f0 5"),
    ("an error map's notes too short to hear", "bench map --seconds 0.01"),
    ("an error map's model that is not there", "bench map --model nosuch"),
    # playing live (no server named so runs here; the rest needs a server: LIVE_ROWS)
    ("windows that are not locked, free, physics or auto", "render --windows sideways x.wav"),
    ("... for a score", "score --presets paper-fb100 --windows both --mix m.wav"),
    ("no JACK server running", "play --server nosuch"),
    ("no polyphony", "play --voices 0"),
    ("a pitch bend range beyond two octaves", "play --bend-range 99"),
    ("FDM past its uniqueness bound", "render --method fdm --fb 10000 -d 0.05 ok2.wav"),
    ("a scene that would need absurd oversampling", "render --method fdm --fb 1e6 --a 1e6 x.wav"),
    # special output paths
    ("output through a symlink (written through)", "render --method fdm -d 0.1 link.wav"),
    ("output to a FIFO (written to, not replaced)", "render --method fdm -d 0.1 fifo"),
    ("read-only existing output", "render --method fdm -d 0.1 ro.wav"),
    ("read-only existing output with --force", "render --method fdm -d 0.1 --force ro2.wav"),
    ("output path is a directory", "render --method fdm -d 0.1 adir"),
    ("output format not supported", "render --method fdm -d 0.1 x.mp3"),
    ("output to standard output", "render --method fdm -d 0.1 -"),
    # files in
    ("WAV cut to half its bytes", "compare half.wav"),
    ("WAV cut by a few bytes", "compare short.wav"),
    ("WAV header promising more data than present", "compare bigheader.wav"),
    ("metadata duration edited", "compare edited.wav"),
    ("FLAC cut short", "compare half.flac"),
    ("lossy OGG compared", "compare ok.ogg"),
    # extreme numbers
    ("bow force 1e308 (FDM)", "render --method fdm --fb 1e308 x.wav"),
    ("bow speed 1e308", "render --method fdm --vb 1e308 x.wav"),
    ("bow force 1e-300", "render --method fdm -d 0.1 --fb 1e-300 x.wav"),
    ("bow force 2.2e-309, subnormal (operator)", "render -d 0.1 --fb 2.2e-309 x.wav"),
    ("f0 16 kHz at 44.1 kHz (FDM)", "render --method fdm -d 0.1 --f0 16000 x.wav"),
    ("f0 1e-300", "render --method fdm --f0 1e-300 x.wav"),
    ("friction shape 5e-324", "render --a 5e-324 x.wav"),
    ("huge oversampling", "render --method fdm --oversample 100000 x.wav"),
    ("an hour at 384 kHz", "render --method fdm -d 3600 --sr 384000 x.wav"),
    ("fixed gain that would clip", "render --method fdm -d 0.1 --gain 120 x.wav"),
    ("infinite training budget", "train --fb 100 --minutes inf"),
    ("training budget 1e308 minutes", "train --fb 100 --minutes 1e308"),
    ("10^18 training steps", "train --fb 100 --steps 1000000000000000000"),
    ("a network 10^9 wide", "train --fb 100 --width 1000000000"),
    ("compare reference past two minutes of FDM", "compare long.wav --reference high"),
    ("1000-voice mix", "score --score big.toml --method fdm --mix -q mix.wav"),
    # scores, MIDI and pitch names
    ("MIDI input that is not a MIDI file", "score --score notmidi.mid --method fdm --mix m.wav"),
    ("empty MIDI file", "score --score empty.mid --method fdm --mix m.wav"),
    ("MIDI file with no notes", "score --score notempo.mid --method fdm --mix m.wav"),
    ("notes outside every model's range", "score --score uncovered.toml --mix m.wav"),
    ("unknown score key", "score --score unknownkey.toml --method fdm --mix m.wav"),
    ("pitch and f0 both given", "score --score pitchf0.toml --method fdm --mix m.wav"),
    ("voice defined twice", "score --score twice.toml --method fdm --mix m.wav"),
    ("curve times not increasing", "score --score unsorted.toml --method fdm --mix m.wav"),
    ("note start < 0", "score --score negstart.toml --method fdm --mix m.wav"),
    ("pitch name H4 (German B)", "render --method fdm --pitch H4 x.wav"),
    ("pitch name A10 (above B8)", "render --method fdm --pitch A10 x.wav"),
    # model files that lie or break
    ("model file whose window tensor was scaled 1e6 (digest recomputed)", "render --fb 100 --model window.safetensors x.wav"),
    ("model file with a 0 x 0 domain mask (digest recomputed)", "render --fb 100 --model mask0.safetensors x.wav"),
    # run in its own directory: a damaged model in the table's ./models would be skipped (and named) in every row
    ("... the same file in ./models: skipped, named, the shipped model plays", "render --fb 100 -d 0.1 x.wav",
     "damaged"),
    ("model file claiming 1.1x its bow force (digest recomputed)", "render --fb 110 --model liar.safetensors x.wav"),
    ("model file claiming twice its range of states (digest recomputed)",
     "render --fb 100 --model states.safetensors x.wav"),
    ("model path: a symlink to /dev/zero", "render --fb 100 --model zero.safetensors x.wav"),
    ("model path: a directory", "render --fb 100 --model adir.safetensors x.wav"),
    ("model path: a symlink loop", "render --fb 100 --model loop.safetensors x.wav"),
    ("model path: a FIFO", "render --fb 100 --model mfifo.safetensors x.wav"),
    ("score: a FIFO with no suffix (never opened to sniff it)", "score --score sfifo --mix m.wav"),
    ("compare: a directory", "compare adir.safetensors"),
    ("compare: /dev/null", "compare /dev/null"),
    ("train --config: a FIFO", "train --config sfifo"),
    # MIDI files
    ("MIDI file timed in SMPTE frames", "score --score smpte.mid --method fdm --mix m.wav"),
    ("MIDI file with 0 ticks per beat", "score --score zerodiv.mid --method fdm --mix m.wav"),
    ("MIDI header announcing 65535 tracks, five present", "score --score tracks.mid --method fdm --mix m.wav"),
    ("four parts on their own tracks, all on channel 1, a unison", "score --score chorale.mid --method fdm --mix m.wav"),
    # whole jobs, numbers, files
    ("a note starting at 3000 s (mix estimated as a whole)", "score --score late.toml --mix m.wav"),
    ("a note starting at 1e12 s, with --force", "score --score later.toml --mix m.wav --force"),
    ("a score nested 5000 deep", "score --score deep.toml --method fdm --mix m.wav"),
    ("a preset given as a path", "render --preset ../../etc/passwd x.wav"),
    ("train --window-ms 1e-320", "train --fb 100 --window-ms 1e-320 --steps 1 --out w.safetensors"),
    ("train --band-seconds 0", "train --fb 60:80 --band-seconds 0 --steps 1 --out b.safetensors"),
    ("train --deriv -1", "train --fb 100 --deriv -1 --steps 1 --out d.safetensors"),
    ("train --rollout -1", "train --fb 100 --rollout -1 --steps 1 --out r.safetensors"),
    ("bow force 1e-320 (an all-zero render)", "render --method fdm -d 0.1 --fb 1e-320 x.wav"),
    ("compare against a silent reference", "compare plain.wav --vb -0.0"),
    ("scene flags on a file that carries its scene", "compare ok.wav --vb 0.1"),
    ("two empty WAVs", "compare e1.wav e2.wav"),
    ("metadata edited: render_seconds \"fast\"", "compare fast.wav"),
    ("metadata edited: signal \"x\"", "compare sigx.wav"),
    ("a stems index edited: duration \"abc\"", "compare stemmed.wav"),
    ("a 300-character output name", "render --method fdm -d 0.1 " + "a" * 300 + ".wav"),
    ("models --only a name no model has", "models --only soft-range,soft-rnage --report m.html"),
]

# (what, command, signal, seconds after start-up): the signal lands in the phase named
SIGNALS = [
    ("Ctrl-C during a long FDM render", "render --method fdm --oversample 200 -d 200 --force sig.wav", "SIGINT", 3),
    ("SIGTERM during a long FDM render", "render --method fdm --oversample 200 -d 200 --force sig.wav", "SIGTERM", 3),
    ("SIGTERM during compare's x100 reference", "compare long.wav --reference high --force", "SIGTERM", 3),
    ("Ctrl-C during training data preparation", "train --fb 100 --n-data 1000000 --steps 5 --out t.safetensors",
     "SIGINT", 3),
    ("SIGTERM while training (after its first checkpoint)", "train --fb 100 --width 16 --depth 2 --n-data 64 "
     "--minutes 10 --checkpoint-every 1 --out tt.safetensors", "SIGTERM", "tt.ckpt.safetensors"),
    ("Ctrl-C while blocked writing to a FIFO nobody reads", "render --method fdm -d 0.1 lonely", "SIGINT", 4),
]


def main():
    exe = [sys.executable, "-m", "bowsynth"]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        (d / "garbage.safetensors").write_bytes(b"\x00garbage" * 10)
        (d / "garbage.wav").write_bytes(b"RIFF0000WAVEjunk" * 4)
        (d / "bad.toml").write_text("[[voice]\nfb = ")
        (d / "exists.safetensors").write_bytes(b"x")
        (d / "unfinished.ckpt.safetensors").write_bytes(b"x")  # only its presence is asked before training
        sf.write(d / "plain.wav", np.zeros(100), 44100)
        subprocess.run(exe + ["render", "--method", "fdm", "-d", "0.1", "ok.wav"], cwd=d, check=True,
                       capture_output=True)
        import json

        import torch
        from safetensors.torch import save_file

        save_file({"w": torch.zeros(1)}, str(d / "v9.safetensors"),
                  metadata={"bowsynth": json.dumps({"format": "bowsynth-operator", "format_version": 9})})
        _path_files(d, exe)
        _model_and_score_files(d, exe)
        env = {"COLUMNS": "400", "PATH": "/usr/bin:/bin", "HOME": str(d), "TMPDIR": str(d / "tmp"),
               "PYTHONPATH": os.environ.get("PYTHONPATH", "")}
        print("| bad input | command | exit code | what bowsynth says |")
        print("|---|---|---|---|")
        for what, cmd, *sub in CASES:  # (what, command[, the subdirectory it runs in])
            reader = _drain(d / "fifo") if "fifo" in cmd.split() else None
            r = subprocess.run(exe + cmd.split(), cwd=d.joinpath(*sub), capture_output=True, env=env)
            if reader:
                reader.join(10)
            err = r.stderr.decode(errors="replace")
            if cmd.split()[-1] == "-":
                err += f"(stdout: {len(r.stdout)} bytes starting {r.stdout[:4]!r})"
            elif r.returncode == 0:
                lines = r.stdout.decode(errors="replace").splitlines()
                shown = [ln for ln in lines if ln.startswith(("wrote", "note:"))]
                err += "".join(f"\n(stdout) {ln}" for ln in shown)
            print(f"| {what} | `bowsynth {cmd}` | {r.returncode} | {_clean(err, d)} |")
        for what, cmd, sig, wait in SIGNALS:
            p = subprocess.Popen(exe + cmd.split(), cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
            if isinstance(wait, str):  # wait for this file (the first checkpoint), then a little more
                t0 = time.time()
                while not (d / wait).exists() and time.time() - t0 < 300:
                    time.sleep(0.2)
                time.sleep(0.5)
                wait = f"{time.time() - t0:.0f}"
            else:
                time.sleep(wait)
            t0 = time.perf_counter()
            p.send_signal(getattr(signal, sig))
            _, err = p.communicate()
            took = time.perf_counter() - t0
            # torch keeps its own compile cache (torchinductor_<user>) in TMPDIR: a cache, not a file of bowsynth's
            left = sorted(x.name for x in (d / "tmp").iterdir() if not x.name.startswith("torchinductor"))
            left += sorted(x.name for x in d.glob(".*.tmp"))
            print(f"| {what} | `bowsynth {cmd}`, {sig} after {wait} s | {p.returncode} | {_clean(err.decode(), d)} "
                  f"(exit {took:.2f} s after the signal; temp files left: {', '.join(left) or 'none'}) |")
            for name in left:
                (d / "tmp" / name).unlink(missing_ok=True)
                (d / name).unlink(missing_ok=True)
        for row in LIVE_ROWS:
            print(row)
        print(f"\nFiles after the special-path rows: link.wav is still a symlink: {(d / 'link.wav').is_symlink()}; "
              f"fifo is still a FIFO: {stat.S_ISFIFO(os.stat(d / 'fifo').st_mode)}; ro.wav untouched: "
              f"{(d / 'ro.wav').read_bytes() == b'precious'}; ro2.wav mode after --force: "
              f"{stat.S_IMODE(os.stat(d / 'ro2.wav').st_mode):o}; the 1000-voice mix's metadata: "
              f"{_mix_summary(d / 'mix.wav')}")


def _mix_summary(path: Path) -> str:
    import json

    m = json.loads(sf.SoundFile(str(path)).comment)
    return f"voices {m['voices']}, {len(m['names'])} names kept, names_truncated {m.get('names_truncated', False)}"


def _clean(err: str, d: Path) -> str:
    msg = " / ".join(line for line in err.strip().splitlines() if line.strip()) or "(nothing)"
    return msg.replace(str(d) + "/", "").replace("|", "\\|")


def _drain(fifo: Path) -> threading.Thread:
    def read():
        with open(fifo, "rb") as f:
            f.read()

    t = threading.Thread(target=read, daemon=True)
    t.start()
    return t


def _path_files(d: Path, exe) -> None:
    (d / "tmp").mkdir()
    (d / "t").mkdir()
    (d / "adir").mkdir()
    (d / "link.wav").symlink_to(d / "t" / "real.wav")
    os.mkfifo(d / "fifo")
    os.mkfifo(d / "lonely")
    for name in ("ro.wav", "ro2.wav"):
        (d / name).write_bytes(b"precious")
        (d / name).chmod(0o444)
    ok = (d / "ok.wav").read_bytes()
    (d / "half.wav").write_bytes(ok[:len(ok) // 2])
    (d / "short.wav").write_bytes(ok[:-6])
    big = bytearray(ok)
    i = big.find(b"data")
    big[i + 4:i + 8] = (int.from_bytes(big[i + 4:i + 8], "little") + 4000).to_bytes(4, "little")
    (d / "bigheader.wav").write_bytes(bytes(big))
    (d / "edited.wav").write_bytes(ok.replace(b'"duration":0.1', b'"duration":0.2'))
    for args in (["-d", "0.5", "ok.flac"], ["-d", "0.5", "ok.ogg"], ["-d", "300", "long.wav"]):
        subprocess.run(exe + ["render", "--method", "fdm", *args], cwd=d, check=True, capture_output=True)
    flac = (d / "ok.flac").read_bytes()
    (d / "half.flac").write_bytes(flac[:len(flac) // 2])
    _score_files(d)
    (d / "big.toml").write_text("[defaults]\nduration = 0.01\n" + "".join(
        f'[[voice]]\nname = "voice-number-{i}"\nfb = {50 + i % 50}\n' for i in range(1000)))


def _forge(d: Path, name: str, edit_tensors=None, edit_meta=None) -> None:
    """A copy of paper-fb100 edited as an attacker would: the digest recomputed over the edit."""
    import json

    from safetensors import safe_open
    from safetensors.numpy import save_file

    from bowsynth.engines.operator.choose import SHIPPED_DIR
    from bowsynth.engines.operator.modelfile import digest

    with safe_open(str(SHIPPED_DIR / "paper-fb100.safetensors"), framework="numpy") as f:
        meta = json.loads(f.metadata()["bowsynth"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    (edit_tensors or (lambda t: None))(tensors)
    (edit_meta or (lambda m: None))(meta)
    meta["digest"] = digest(meta, tensors)
    save_file(tensors, str(d / name), metadata={"bowsynth": json.dumps(meta)})


def _model_and_score_files(d: Path, exe) -> None:
    import json

    import mido

    _forge(d, "window.safetensors", lambda t: t.update(window=np.array(t["window"] * 1e6, dtype=np.float32)))
    _forge(d, "mask0.safetensors", lambda t: t.update({"domain.mask": np.zeros((0, 0), np.uint8)}))

    def more_force(m):
        m["domain"]["beta"] *= 1.1
        m["scene"]["fb"] *= 1.1
    _forge(d, "liar.safetensors", edit_meta=more_force)

    def more_states(m):
        m["domain"]["q_lo"] *= 2.0
        m["domain"]["q_hi"] *= 2.0
    _forge(d, "states.safetensors", edit_meta=more_states)
    (d / "damaged" / "models").mkdir(parents=True)
    (d / "damaged" / "models" / "mask0.safetensors").write_bytes((d / "mask0.safetensors").read_bytes())
    (d / "zero.safetensors").symlink_to("/dev/zero")
    (d / "adir.safetensors").mkdir()
    (d / "loop.safetensors").symlink_to("loop.safetensors")
    os.mkfifo(d / "mfifo.safetensors")
    os.mkfifo(d / "sfifo")
    mid = mido.MidiFile(type=1, ticks_per_beat=480)
    mid.tracks.append(mido.MidiTrack([mido.MetaMessage("set_tempo", tempo=500000, time=0)]))
    for notes in ([72, 74], [67, 65], [67, 62], [48, 43]):
        tr = mido.MidiTrack()
        for n in notes:
            tr += [mido.Message("note_on", note=n, velocity=90, time=0),
                   mido.Message("note_off", note=n, velocity=0, time=480)]
        mid.tracks.append(tr)
    mid.save(d / "chorale.mid")
    raw = (d / "chorale.mid").read_bytes()
    (d / "smpte.mid").write_bytes(raw[:12] + (0xE728).to_bytes(2, "big") + raw[14:])
    (d / "zerodiv.mid").write_bytes(raw[:12] + (0).to_bytes(2, "big") + raw[14:])
    (d / "tracks.mid").write_bytes(raw[:10] + (65535).to_bytes(2, "big") + raw[12:])
    voice = '[[voice]]\nname = "v"\nf0 = 120.0\nbeta = 0.159155\nduration = 0.1\n'
    (d / "late.toml").write_text(voice + "start = 3000.0\n")
    (d / "later.toml").write_text(voice + "start = 1e12\n")
    (d / "deep.toml").write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    sf.write(d / "e1.wav", np.zeros(0, "float32"), 44100)
    sf.write(d / "e2.wav", np.zeros(0, "float32"), 44100)
    for name, key, value in (("fast.wav", "render_seconds", "fast"), ("sigx.wav", "signal", "x")):
        with sf.SoundFile(str(d / "ok.wav")) as f:
            data, meta = f.read(dtype="float32"), json.loads(f.comment)
        meta[key] = value
        with sf.SoundFile(str(d / name), "w", samplerate=44100, channels=1, subtype="FLOAT") as f:
            f.comment = json.dumps(meta)
            f.write(data)
    (d / "one.toml").write_text(voice)
    subprocess.run(exe + ["score", "--score", "one.toml", "--method", "fdm", "--mix", "stemmed.wav", "--stems",
                          "stemmed"], cwd=d, check=True, capture_output=True)
    idx = d / "stemmed" / "notes.json"
    doc = json.loads(idx.read_text())
    doc["notes"][0]["duration"] = "abc"
    idx.write_text(json.dumps(doc))


# What needs a running jackd and a test client is run by tests/test_live.py (a real server, dummy driver); these rows
# say what those tests assert
LIVE_ROWS = [
    "| a --connect port that does not exist | `bowsynth play --server S --connect nowhere:nothing` | 2 | error: "
    "--connect nowhere:nothing: no such audio input port on the JACK server (audio inputs: ...) (tests/test_live.py) |",
    "| the JACK server goes away while playing | kill jackd under `bowsynth play` | 1 | the summary line, then error: "
    "the JACK server went away while playing (...); start it again and rerun bowsynth play (tests/test_live.py) |",
    "| garbage MIDI bytes, a flood of 10,000 notes a second | (test client: data bytes as status, a status byte in "
    "data, a 2-byte note-on; 3,000 notes in 0.3 s) | - | keeps playing in time; the summary counts the dropped bytes, "
    "the deferred and dropped notes (tests/test_live.py) |",
    "| SIGINT / SIGTERM while playing | `bowsynth play`, a signal mid-note | 130 / 143 | the summary line, the client "
    "closed, the server left running (tests/test_live.py) |",
]


def _score_files(d: Path) -> None:
    import mido

    (d / "notmidi.mid").write_text("not a midi file")
    mido.MidiFile(type=1).save(d / "empty.mid")
    mid = mido.MidiFile(type=0)
    mid.tracks.append(mido.MidiTrack([mido.MetaMessage("set_tempo", tempo=400_000, time=0)]))
    mid.save(d / "notempo.mid")
    note = '[[voice]]\nname = "v"\n[[voice.note]]\nduration = 0.1\n'
    (d / "uncovered.toml").write_text(note + 'pitch = "A4"\nbeta = 2.0\n')
    (d / "unknownkey.toml").write_text(note + 'pitch = "A4"\nvelocity = 3\n')
    (d / "pitchf0.toml").write_text(note + 'pitch = "A4"\nf0 = 440.0\n')
    (d / "twice.toml").write_text('[[voice]]\nname = "a"\n[[voice]]\nname = "a"\n')
    (d / "unsorted.toml").write_text(note + "fb = [[0.5, 100.0], [0.2, 50.0]]\n")
    (d / "negstart.toml").write_text(note + "start = -0.5\n")


if __name__ == "__main__":
    main()
