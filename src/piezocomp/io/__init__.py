"""File input and output: scanner-model files, real AFM images and recorded time series.

- :mod:`.model_files`: scanner-model files (versioned JSON);
- :mod:`.signals`: recorded time series (CSV or NPZ);
- :mod:`.dataclass_toml`: frozen dataclasses (settings) as TOML, written and read back;
- :mod:`.afm_scan` (one image structure for every vendor), :mod:`.afm_files` (the readers,
  series of images and ``.gwy`` writing), :mod:`.bruker` (Nanoscope files), :mod:`.nanonis_sxm`
  (Nanonis images), :mod:`.jpk` (JPK images) and :mod:`.hs_afm` (high-speed AFM movies).

Readers of vendor formats are optional extras (``pip install '.[files]'`` in piezocomp's folder).

May import the core only.
"""

from piezocomp._atomic import atomic_write_text
from piezocomp.io.afm_files import read_scan, read_series, write_gwy
from piezocomp.io.afm_scan import AfmFileError, AfmScan, MissingReaderError
from piezocomp.io.model_files import load_model, model_from_json, model_to_json, save_model
from piezocomp.io.signals import RecordedSignal, read_signal, write_signal

__all__ = [
    "AfmFileError",
    "AfmScan",
    "MissingReaderError",
    "RecordedSignal",
    "atomic_write_text",
    "load_model",
    "model_from_json",
    "model_to_json",
    "read_scan",
    "read_series",
    "read_signal",
    "save_model",
    "write_gwy",
    "write_signal",
]
