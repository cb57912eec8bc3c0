"""File input and output: real AFM images and recorded time series.

Readers of vendor formats are optional extras (``pip install piezocomp[files]``).
"""

from piezocomp.io.afm_files import AfmFileError, AfmScan, MissingReaderError, read_scan, write_gwy
from piezocomp.io.signals import RecordedSignal, read_signal, write_signal

__all__ = [
    "AfmFileError",
    "AfmScan",
    "MissingReaderError",
    "RecordedSignal",
    "read_scan",
    "read_signal",
    "write_gwy",
    "write_signal",
]
