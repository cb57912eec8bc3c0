"""Drift compensation over a 20-minute session of Table I moves on a drifting cpr5.

For ``cpr5`` and ``cpr5-warmup``: the worst true error of the session's images with no
compensation, creep-and-hysteresis only, drift only and both, and the share of time spent
measuring drift. The creep-and-hysteresis models are identified without a sensor (both
axes, the settings of ``piezocomp reproduce``) twice: on the drifting scanner itself, and on
its drift-free twin (the same scanner identified while drift is negligible), to separate
what drift does to the identification from what the drift compensator does.

Takes about 10 minutes on two cores::

    python benchmarks/drift_session.py
"""

from __future__ import annotations

from dataclasses import replace

from piezocomp.experiments import drift_session as D
from piezocomp.experiments.methods import IdentificationSettings, MethodModels, identification_job
from piezocomp.virtual_afm import VirtualAFM, load_config


def models_for(config, seed=1):
    jobs = [identification_job("sensorless", a, config, seed, IdentificationSettings())
            for a in "xy"]  # fmt: skip
    return MethodModels.from_jobs(jobs, VirtualAFM(config, seed=seed).sample_period_s)


def main() -> None:
    calm = replace(load_config("cpr5").scanner, drift_nm_per_s=0.0,
                   drift_random_walk_nm_per_sqrt_s=0.0)  # fmt: skip
    twin = models_for(replace(load_config("cpr5"), scanner=calm))
    for preset in ("cpr5", "cpr5-warmup"):
        config = load_config(preset)
        for label, models in (("identified on the drifting scanner", models_for(config)),
                              ("identified on its drift-free twin", twin)):  # fmt: skip
            print(f"{preset}, models {label}:")
            s = D.DriftSessionSettings(minutes=20.0, area_nm=600.0)
            for m in D.METHODS:
                afm = VirtualAFM(config, seed=1)
                try:
                    inst, origin = D.session_instrument(m, afm, models, s)
                    r = D.run(inst, s, origin_nm=origin, truth=afm.truth)
                except (ValueError, RuntimeError) as exc:
                    print(f"  {m:17s} failed: {exc}")
                    continue
                print(
                    f"  {m:17s} worst true error {r.true_max_error_nm:7.2f} nm, measured "
                    f"{r.max_error_nm:7.2f} nm, measuring {100 * r.overhead_fraction:4.1f} %"
                )


if __name__ == "__main__":
    main()
