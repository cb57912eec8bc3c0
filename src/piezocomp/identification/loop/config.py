"""The loop stage's settings: :class:`LoopConfig` (``loop`` in
:class:`~piezocomp.identification.config.IdentifyConfig`)."""

from __future__ import annotations

from dataclasses import dataclass

from piezocomp._validation import check_int_at_least

__all__ = ["LoopConfig"]


@dataclass(frozen=True)
class LoopConfig:
    """The steady loop of Section IV.

    Parameters
    ----------
    degree : int
        Degree of the loop polynomial ``f_a`` of eq (23) (>= 5 in the paper).
    """

    degree: int = 5

    def __post_init__(self) -> None:
        check_int_at_least("degree", self.degree, 1)
