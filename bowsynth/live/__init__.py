"""Live playing: the streaming engine (`stream.Stream`, MIDI events in, audio blocks out) and the JACK client
(`jack_client.play`) that `bowsynth play` runs."""

from .stream import Stream

__all__ = ["Stream"]
