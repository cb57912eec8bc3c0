"""Subcommands of the ``piezocomp`` CLI, one module each (see :mod:`piezocomp.cli`).

Modules without a ``register`` function are shared by several subcommands, not subcommands:
:mod:`._common` (time series), :mod:`.instrument_options` (``--instrument`` and its options),
:mod:`.identify_outputs` (what ``identify`` writes), and the instrument halves of ``identify``
and ``reproduce`` (:mod:`.identify_instrument`, :mod:`.reproduce_instrument`).
"""

COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("bench", "measure forward/inverse throughput and the streaming step time"),
    "calibrate": (
        "calibrate", "measure the speed a full-range scan is as wide as commanded, on a grating"
    ),
    "compensate": ("compensate", "turn a desired trajectory into the command that produces it"),
    "drift": ("drift", "measure an instrument's drift from a series of images of one area"),
    "emulate": (
        "emulate", "serve the Nanonis TCP protocol on loopback with the virtual AFM behind it"
    ),
    "fit": ("fit", "identify a scanner model from a record of command and measured extension"),
    "identify": (
        "identify",
        "identify the scanner model with the AFM as its own sensor (virtual AFM, a record, "
        "or an instrument)",
    ),
    "loop": (
        "loop",
        "fit the hysteresis loop from a real image's trace/retrace (Sec. IV) and correct it",
    ),
    "reproduce": (
        "reproduce", "the paper's experiments (Table I, Figs 8-10) end to end on the virtual AFM"
    ),
    "simulate": ("simulate", "run the forward model on a command trajectory"),
    "simulate-afm": (
        "simulate_afm", "acquire an image on the virtual AFM (PNG, NPZ and ground truth)"
    ),
    "waveform": (
        "waveform", "write the identification waveform (Fig. 7a) to run on a real instrument"
    ),
}  # fmt: skip
"""Each subcommand: the module of this package that defines it (its ``register``) and its
one-line help. ``piezocomp --help`` lists these without importing any command's module, and
a command line imports only the module of its command, so that the command line starts at
once (numba, scipy and the identification load only for the command that needs them)."""
