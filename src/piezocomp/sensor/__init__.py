"""Identification of the scanner model (14) with a position sensor.

For closed-loop scanners and test rigs, where a sensor measures the extension ``y`` beside
the command ``u``: :mod:`.fit` (non-negative least squares, then the batch refinement of the
sensorless pipeline), :mod:`.orders` (the orders chosen on held-out samples) and
:mod:`.record` (the split of a record and its error figures). ``piezocomp fit`` runs them.

May import the core and :mod:`piezocomp.identification` (its batch refinement, parameter
layout and excitation checks); the sensorless identification never imports this package.
"""
