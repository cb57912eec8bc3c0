"""Backends for real controllers: each an :class:`~piezocomp.instrument.Instrument`.

A backend turns the interface's calls (straight moves, streamed set-points, line records,
images, pushes with Z feedback off) into a controller's own commands, converting units at its
boundary only (metres and volts there, nm and s inside) and checking range and slew before
anything is sent. The virtual AFM (:mod:`piezocomp.virtual_afm`) implements the same interface
and is the model to follow; its docstrings say what each method must guarantee.

- :mod:`.pacing`: set-points paced by the client, the session's timing log and
  :class:`~piezocomp.drivers.pacing.TimingError` (any backend that streams);
- :mod:`.nanonis_protocol`: the Nanonis TCP framing both ways and a checked connection;
- :mod:`.nanonis_controller`: what the Nanonis backend reads and sets at connection;
- :mod:`.nanonis`: :class:`~piezocomp.drivers.nanonis.NanonisInstrument`, the Nanonis
  backend (``--instrument nanonis://HOST:PORT``);
- :mod:`.nanonis_emulator`: a Nanonis controller emulated on loopback over the virtual AFM
  (``piezocomp emulate``).

Backends import the core only (and their sibling modules here). The emulator is the one
exception: it imports :mod:`piezocomp.virtual_afm` to serve it, and no backend imports the
emulator. See ``docs/instruments.md``.
"""
