"""Write examples/melody.mid: a type 1 MIDI file with a tempo change, a held C3 (channel 1) and a melody (channel 2)
whose last two notes overlap. All at velocity 64, the shipped paper-fb100 model's bow, so the default operator plays
it:

    python examples/make_melody_mid.py && bowsynth score --score examples/melody.mid --mix melody.wav
"""

from pathlib import Path

import mido

TPB = 480


def main(path=Path(__file__).resolve().parent / "melody.mid"):
    mid = mido.MidiFile(type=1, ticks_per_beat=TPB)
    tempo = mido.MidiTrack([mido.MetaMessage("track_name", name="tempo"),
                            mido.MetaMessage("set_tempo", tempo=mido.bpm2tempo(120), time=0),
                            mido.MetaMessage("set_tempo", tempo=mido.bpm2tempo(90), time=4 * TPB)])
    held = mido.MidiTrack([mido.MetaMessage("track_name", name="drone"),
                           mido.Message("note_on", channel=0, note=48, velocity=64, time=0),
                           mido.Message("note_off", channel=0, note=48, velocity=0, time=8 * TPB)])
    mel = mido.MidiTrack([mido.MetaMessage("track_name", name="melody")])
    beats = [(64, 1), (67, 1), (72, 1), (71, 1), (69, 2)]  # E4 G4 C5 B4 A4
    for note, length in beats:
        mel.append(mido.Message("note_on", channel=1, note=note, velocity=64, time=0))
        mel.append(mido.Message("note_on", channel=1, note=note, velocity=0, time=length * TPB))
    # two overlapping notes to close: G4 from beat 6, E4 from beat 6.5, both to beat 8
    mel.append(mido.Message("note_on", channel=1, note=67, velocity=64, time=0))
    mel.append(mido.Message("note_on", channel=1, note=64, velocity=64, time=TPB // 2))
    mel.append(mido.Message("note_on", channel=1, note=67, velocity=0, time=3 * TPB // 2))
    mel.append(mido.Message("note_on", channel=1, note=64, velocity=0, time=0))
    mid.tracks += [tempo, held, mel]
    mid.save(path)
    return path


if __name__ == "__main__":
    print(main())
