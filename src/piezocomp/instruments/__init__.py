"""Backends for real controllers: each an :class:`~piezocomp.instrument.Instrument`.

A backend turns the interface's calls (straight moves, streamed set-points, line records,
images, pushes with Z feedback off) into a controller's own commands, converting units at its
boundary only (metres and volts there, nm and s inside) and checking range and slew before
anything is sent. The virtual AFM (:mod:`piezocomp.virtual_afm`) implements the same interface
and is the model to follow; its docstrings say what each method must guarantee.

May import the core only.
"""
