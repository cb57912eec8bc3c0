"""The virtual AFM: a simulated instrument whose scanner behaves like the paper's.

A Veeco AutoProbe CP-R with a 5 um tube scanner in tapping mode over 15 nm gold particles
(Mokaberi & Requicha 2008, Sections I-II, V). Per axis: a Preisach hysteresis operator
with a smooth density evaluated exactly (:mod:`.preisach`), logarithmic creep as a dense
spectrum of first-order modes (:mod:`.creep`), thermal drift and x-y cross-coupling
(:mod:`.scanner`); spheres on a rough plane imaged by a sphere-ended cone (:mod:`.sample`),
pushed with Z feedback off with a friction of each particle's own and pushes that sometimes
fail (:mod:`.pushing`, :mod:`.worked_sample`); or a calibration grating of known pitch
instead of the particles (:mod:`.grating`), the length reference of a lateral calibration.
:class:`VirtualAFM` implements :class:`piezocomp.instrument.Instrument`; its ground truth
(:mod:`.ground_truth`) is behind ``afm.truth`` (never for compensation code).
Configuration: :mod:`.config` and the presets in ``presets/*.toml``: ``cpr5`` (default: the
paper's scanner, drifting as in air after warm-up), ``cpr5-nodrift`` (the same without drift),
``cpr5-warmup`` (warming up), ``gentle`` and ``harsh``.

Its physics (Preisach hysteresis, its creep) is deliberately not the identified model's family.
May import the core only; imported only by :mod:`piezocomp.experiments`, the command line and
the Nanonis emulator (:mod:`piezocomp.drivers.nanonis_emulator`, which serves it over the
Nanonis protocol and never reads its truth). Its drift (:mod:`.scanner`) is the physics being
simulated; :mod:`piezocomp.drift` is the software that measures and compensates drift.
:mod:`.calibration` sets the scanner's physics to the paper's magnitudes; :mod:`.grating` is a
sample. :mod:`.ground_truth` is what the simulator knows; :mod:`.truth_log` the recent true
positions it keeps for that.
"""

from piezocomp.virtual_afm.config import AFMConfig, config_to_toml, list_presets, load_config
from piezocomp.virtual_afm.grating import Grating
from piezocomp.virtual_afm.ground_truth import GroundTruth
from piezocomp.virtual_afm.instrument import VirtualAFM
from piezocomp.virtual_afm.scanner import scanner_params_from_config

__all__ = [
    "AFMConfig",
    "Grating",
    "GroundTruth",
    "VirtualAFM",
    "config_to_toml",
    "list_presets",
    "load_config",
    "scanner_params_from_config",
]
