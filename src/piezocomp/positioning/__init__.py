"""Positioning in true lengths: the inverse model between a user's coordinates and the scanner.

- :mod:`.compensated`: :class:`CompensatedInstrument`, an :class:`~piezocomp.instrument.Instrument`
  whose positions are true nanometres (moves, images, pushes through the inverse model, eqs 8-13,
  one predicted state carried across calls);
- :mod:`.axis_compensation`: the per-axis compensators it is built from (model, inverse, domain);
- :mod:`.assembly`: automatic assembly of particles into patterns (assign, plan, push, check),
  with :mod:`.push_check` (where each pushed particle went, from images).

May import the core (``model``, ``inverse``, ``limits``, ``instrument``, ``tip``) and
:mod:`piezocomp.imaging`; never the virtual AFM, identification or experiments.
"""

from piezocomp.positioning.compensated import CompensatedInstrument

__all__ = ["CompensatedInstrument"]
