"""``piezocomp simulate-afm`` through ``main``."""

import numpy as np

from piezocomp.cli import main


def test_simulate_afm_writes_images_data_config_and_truth(tmp_path):
    out = tmp_path / "run"
    rc = main(["simulate-afm", "--preset", "gentle", "--out", str(out), "--pixels", "24",
               "--size-nm", "200", "--seed", "3"])  # fmt: skip
    assert rc == 0
    for name in ("forward.png", "backward.png", "image.npz", "config.toml",
                 "truth_particles.csv", "truth_tip_nm.npz"):  # fmt: skip
        assert (out / name).stat().st_size > 0
    with np.load(out / "image.npz") as d:
        assert d["forward_nm"].shape == (24, 24)
    assert "seed = 3" in (out / "config.toml").read_text()
    # the Gwyddion file holds both traces, the same data
    from piezocomp.io import read_scan

    gwy = read_scan(out / "image.gwy")
    with np.load(out / "image.npz") as d:
        np.testing.assert_allclose(gwy.forward_nm, d["forward_nm"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(gwy.backward_nm, d["backward_nm"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(gwy.size_nm, (200.0, 200.0), rtol=1e-12)
    # the saved configuration is accepted back as a scanner file
    assert main(["simulate-afm", "--scanner", str(out / "config.toml"), "--out",
                 str(tmp_path / "again"), "--pixels", "8"]) == 0  # fmt: skip


def test_bad_config_prints_one_line_and_exits_2(tmp_path, capsys):
    f = tmp_path / "bad.toml"
    f.write_text("[sample]\ntip_radius_nm = -3\n")
    assert main(["simulate-afm", "--scanner", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "sample.tip_radius_nm must be > 0. Got -3.0." in err
