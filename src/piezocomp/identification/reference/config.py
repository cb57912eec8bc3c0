"""The reference stage's settings: :class:`ReferenceConfig` (``reference`` in
:class:`~piezocomp.identification.config.IdentifyConfig`)."""

from __future__ import annotations

from dataclasses import dataclass

from piezocomp._validation import check_finite_scalar

__all__ = ["ReferenceConfig"]


@dataclass(frozen=True)
class ReferenceConfig:
    """The length reference (:mod:`~piezocomp.identification.reference.grating`,
    :mod:`~piezocomp.identification.reference.scaling`).

    Parameters
    ----------
    grating : bool
        Whether a calibration grating of known pitch, scanned with the same scanner, scales
        the models (particles cannot give the scale).
    grating_pitch_nm : float, optional
        Its pitch (``None``: the virtual AFM's grating; a recorded grating needs it).
    grating_path : {"auto", "minor_loops", "steady"}
        What the grating's scan does along the axis
        (:func:`~piezocomp.identification.reference.grating.measure_grating`'s ``path``):
        minor loops with rests (the scale of positioning's paths), or the paper's steady
        cycles; ``"auto"``, minor loops where the span holds their sweeps
        (:func:`~piezocomp.identification.reference.grating.grating_path_for`), else steady.
    """

    grating: bool = True
    grating_pitch_nm: float | None = None
    grating_path: str = "auto"

    def __post_init__(self) -> None:
        if not isinstance(self.grating, bool):
            raise TypeError(f"grating must be true or false. Got {self.grating!r}.")
        p = self.grating_pitch_nm
        if p is not None and (
            isinstance(p, bool) or not check_finite_scalar("grating_pitch_nm", p) > 0
        ):
            raise ValueError(f"grating_pitch_nm must be None or > 0. Got {p!r}.")
        if self.grating_path not in ("auto", "minor_loops", "steady"):
            raise ValueError(
                "grating_path must be 'auto', 'minor_loops' or 'steady'. "
                f"Got {self.grating_path!r}."
            )
