"""Draw docs/figures/drift_sign.png: the sign convention of drift.csv on the real .sxm pair of
tests/data/afm_files (run from the repository's root: python docs/figures/drift_sign.py)."""

from pathlib import Path

import numpy as np

from piezocomp.io import read_scan
from piezocomp.plotting import new_figure, save_figure

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "afm_files"
a, b = (read_scan(DATA / f"sxm_pair_{k}.sxm") for k in "AB")
dx, dy = -20 / 64, -12 / 64  # B's content lies here from A's (the crops' offset)
fig, axes = new_figure(1, 2, figsize=(9.5, 4.9), layout="constrained")
extent = (0.0, a.size_nm[0], 0.0, a.size_nm[1])
x0, y0 = 2.28, 0.56  # a bright feature of A, and where it lies in B
for ax, scan, name in zip(axes, (a, b), ("A (first)", "B (82 s later)"), strict=True):
    z = scan.forward_nm - np.median(scan.forward_nm, axis=1, keepdims=True)
    ax.imshow(z, origin="lower", extent=extent, cmap="afmhot", interpolation="nearest")
    ax.set_title(f"{name}, upright: row 0 at the bottom")
    ax.set_xlabel("x (nm): along the forward line")
    ax.set_ylabel("y (nm)")
axes[0].plot([x0], [y0], "o", mfc="none", mec="c", ms=14, mew=2)
axes[1].plot([x0], [y0], "o", mfc="none", mec="c", ms=14, mew=2, alpha=0.5)
axes[1].plot([x0 + dx], [y0 + dy], "o", mfc="none", mec="c", ms=14, mew=2)
axes[1].annotate("", xy=(x0 + dx, y0 + dy), xytext=(x0, y0),
                 arrowprops={"arrowstyle": "->", "color": "c", "lw": 2})  # fmt: skip
axes[1].text(0.1, 2.3, f"content moved by\nmeasured_x_nm = {dx:+.3f}\nmeasured_y_nm = {dy:+.3f}",
             color="w", fontsize=9, va="top")  # fmt: skip
save_figure(fig, ROOT / "docs" / "figures" / "drift_sign.png", dpi=90)
