"""Test helpers: the identification configurations the tests run.

Most tests of the pipeline run a smaller working area than ``piezocomp identify``'s default
(1000 nm at three ramp speeds, no calibration cycles): :func:`small` is that configuration,
:func:`small_quick` the same with ``--quick``'s reduced record. Settings are changed by name
(:meth:`~piezocomp.identification.config.IdentifyConfig.updated`).
"""

from typing import Any

from piezocomp.identification.config import IdentifyConfig

SMALL: dict[str, Any] = {"span_nm": 1000.0, "speed_factors": (0.5, 1.0, 2.0), "calibrate": "span"}
"""A 1 um line, part B at 125-500 nm/s, the working span's calibration condition."""


def small(**changes: Any) -> IdentifyConfig:
    """The tests' configuration: the defaults on :data:`SMALL`, then ``changes``."""
    return IdentifyConfig().updated(**{**SMALL, **changes})


def small_quick(**changes: Any) -> IdentifyConfig:
    """:func:`small` with ``--quick``'s reduced record and orders."""
    return IdentifyConfig.quick().updated(**{**SMALL, **changes})
