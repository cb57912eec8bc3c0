"""piezocomp: sensorless compensation of piezo scanner creep and hysteresis.

Implements Mokaberi & Requicha, "Compensation of Scanner Creep and Hysteresis for AFM
Nanomanipulation", IEEE T-ASE 5(2), 2008. Lengths in nm, time in s.

The core, at the top: :mod:`.model` (eq 14), :mod:`.inverse` (eqs 8-13), :mod:`.limits` (travel
range and slew), :mod:`.operators`, :mod:`.instrument` (the interface every instrument
implements, simulated or real) and :mod:`.tip` (the tip's shape, which images and pushes depend
on); beside it :mod:`.bench` (the kernels' throughput, ``piezocomp bench``) and two private
helpers every subpackage may use, ``_atomic`` (files written atomically) and ``_validation``
(input checks). The core imports nothing else of the package but these two. Around it, by
subsystem: ``identification`` (sensorless), ``sensor`` (the fit with a position sensor),
``positioning``, ``drift``, ``imaging`` and ``drivers`` (backends for real controllers) use the
core and never the simulator (the one exception: ``drivers``' Nanonis emulator, which serves
the simulator over the Nanonis protocol); ``virtual_afm`` is the simulator; ``experiments``
runs the paper's experiments, on it or on a real instrument, and alone reads the simulator's
ground truth; ``io``, ``plotting`` and ``commands`` (the command line) serve them all;
``testing`` holds plain-Python oracles of the kernels.

The names a user needs are here, at the top (:data:`__all__`, docs/api.md): the model and
its inverse, the identification, the virtual AFM, the compensated instruments, the model
files and the sensor fit. They are loaded on first use (PEP 562), so ``import piezocomp``
stays fast and loads no subsystem; everything else is reachable by its module.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_WHERE = {
    "ScannerModel": "piezocomp.model",
    "ScannerModel2D": "piezocomp.model",
    "ModelState": "piezocomp.model",
    "Compensator": "piezocomp.inverse",
    "compensate": "piezocomp.inverse",
    "CommandLimits": "piezocomp.limits",
    "Instrument": "piezocomp.instrument",
    "IdentifyConfig": "piezocomp.identification.config",
    "identify": "piezocomp.identification.sensorless",
    "Identification": "piezocomp.identification.result",
    "VirtualAFM": "piezocomp.virtual_afm",
    "CompensatedInstrument": "piezocomp.positioning.compensated",
    "DriftCompensatedInstrument": "piezocomp.drift.compensated",
    "load_model": "piezocomp.io.model_files",
    "save_model": "piezocomp.io.model_files",
    "read_scan": "piezocomp.io.afm_files",
    "fit_sensor": "piezocomp.sensor.fit",
}
"""Each public name of the package's namespace -> the module that defines it."""

__all__ = [
    "CommandLimits",
    "CompensatedInstrument",
    "Compensator",
    "DriftCompensatedInstrument",
    "Identification",
    "IdentifyConfig",
    "Instrument",
    "ModelState",
    "ScannerModel",
    "ScannerModel2D",
    "VirtualAFM",
    "__version__",
    "compensate",
    "fit_sensor",
    "identify",
    "load_model",
    "read_scan",
    "save_model",
]

if TYPE_CHECKING:  # what type checkers and editors see; at run time: __getattr__
    from piezocomp.drift.compensated import DriftCompensatedInstrument
    from piezocomp.identification.config import IdentifyConfig
    from piezocomp.identification.result import Identification
    from piezocomp.identification.sensorless import identify
    from piezocomp.instrument import Instrument
    from piezocomp.inverse import Compensator, compensate
    from piezocomp.io.afm_files import read_scan
    from piezocomp.io.model_files import load_model, save_model
    from piezocomp.limits import CommandLimits
    from piezocomp.model import ModelState, ScannerModel, ScannerModel2D
    from piezocomp.positioning.compensated import CompensatedInstrument
    from piezocomp.sensor.fit import fit_sensor
    from piezocomp.virtual_afm import VirtualAFM


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'piezocomp' has no attribute {name!r}")
    value = getattr(import_module(_WHERE[name]), name)
    globals()[name] = value  # once loaded, an ordinary attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})
