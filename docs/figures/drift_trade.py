"""Draw docs/figures/drift_trade.png: the drift session's accuracy against the share of its
time spent measuring, one point per drift tolerance, from the last generated output of
``session-limits``; ``python docs/figures.py run session-limits`` (or ``read``) redraws it,
and so does ``python docs/figures/drift_trade.py`` from the repository's root."""

import json
from pathlib import Path

from piezocomp.plotting import new_figure, save_figure

ROOT = Path(__file__).resolve().parents[2]
out = json.loads((ROOT / "docs" / "figures" / "generated" / "session-limits.json").read_text())
fig_ = out["figures"]
variants = [("identified", 0.5)] + [
    (v, float(v.split("=")[1])) for v in fig_["variants"].split() if v.startswith("tolerance=")
]
variants.sort(key=lambda v: v[1])


def pair(key: str) -> tuple[float, float]:
    """A 'median / worst' figure of the output."""
    a, b = fig_[key].split(" / ")
    return float(a), float(b)


fig, ax = new_figure(figsize=(6.4, 4.2), layout="constrained")
CURVES = ((0, "o-", "median over the seeds"), (1, "s--", "worst over the seeds (each axis alone)"))
for which, style, label in CURVES:
    xs = [pair(f"{v}.measuring")[which] for v, _ in variants]
    ys = [pair(f"{v}.worst_image_nm")[which] for v, _ in variants]
    ax.plot(xs, ys, style, label=label)
    for x, y, (_, tol) in zip(xs, ys, variants, strict=True):
        ax.annotate(f"{tol:g} nm", (x, y), textcoords="offset points", xytext=(5, 4), fontsize=8)
ax.axhline(1.0, color="0.6", lw=0.8)
ax.axvline(15.0, color="0.6", lw=0.8)
ax.text(15.3, ax.get_ylim()[1] * 0.97, "aim: 15 % measuring", fontsize=8, va="top", color="0.4")
ax.text(ax.get_xlim()[0], 1.03, " aim: 1 nm", fontsize=8, ha="left", color="0.4")
ax.set_xlabel("time spent measuring drift (%)")
ax.set_ylabel("session's worst image, true error (nm)")
ax.set_title(
    f"5-minute session of `both`, seeds {fig_['command'].split('--seeds ')[1].split()[0]} "
    f"(made with {out['made_with']})",
    fontsize=9,
)
ax.legend(fontsize=8, title="each point: a drift tolerance", title_fontsize=8)
save_figure(fig, ROOT / "docs" / "figures" / "drift_trade.png", dpi=90)
