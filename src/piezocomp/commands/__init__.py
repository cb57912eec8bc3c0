"""Subcommands of the ``piezocomp`` CLI, one module each (see :mod:`piezocomp.cli`).

Modules without a ``register`` function are shared by several subcommands, not subcommands:
:mod:`._common` (time series), :mod:`.instrument_options` (``--instrument`` and its options),
:mod:`.identify_outputs` (what ``identify`` writes), and the instrument halves of ``identify``
and ``reproduce`` (:mod:`.identify_instrument`, :mod:`.reproduce_instrument`).
"""
