"""Write the derived pair ``sxm_pair_A.sxm``, ``sxm_pair_B.sxm`` from the real
``STM_nanonis_generic_4_5.sxm`` (run from the repository's root: ``python
tests/data/afm_files/make_sxm_pair.py``).

No public pair of Nanonis images of one area was found. The pair is two 160 x 160 crops of the
real image's Z channel (forward and backward), the second taken 12 lines up and 20 pixels to
the right in the upright image: its content lies 20 pixels left and 12 lines down of where it
is in the first (-0.3125 nm, -0.1875 nm at 0.015625 nm a pixel). Both are stored as the
original was taken (scan direction down). The first keeps the original's record time; the
second is dated 82 s later, one crop's acquisition time (160 lines of 0.512 s), as if taken
straight after. Everything else in the header is the original's.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sxm_files import REAL_SXM, crop_sxm

HERE = Path(__file__).resolve().parent
crop_sxm(HERE / "sxm_pair_A.sxm", REAL_SXM, rows=slice(0, 160), cols=slice(0, 160))
crop_sxm(
    HERE / "sxm_pair_B.sxm", REAL_SXM, rows=slice(12, 172), cols=slice(20, 180),
    rec_time="14:40:06",
)  # fmt: skip
