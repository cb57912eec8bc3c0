"""A failure found while a run is under way exits 1; a request refused before it, 2."""

from __future__ import annotations

import piezocomp.commands.identify as identify_command
from piezocomp.cli import main


def test_identify_exits_1_when_the_identification_fails_during_its_run(tmp_path, monkeypatch,
                                                                       capsys):  # fmt: skip
    def fails(*args, **kwargs):
        raise ValueError("the grating's period was not found in the model's lengths (test)")

    monkeypatch.setattr(identify_command, "identify_virtual", fails)
    out = tmp_path / "run"
    assert main(["identify", "--quick", "--axis", "x", "--no-progress", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    why = "the grating's period was not found in the model's lengths (test)"
    last = "the line at -400 nm on the slow axis"
    assert err[-1] == (f"piezocomp identify: error: axis x: no line gave a model (3 tried; the "
                       f"first: {why}; the last, {last}: {why})")  # fmt: skip
    assert sum("recording again" in line for line in err) == 2  # the two other lines tried


def test_identify_refuses_a_span_before_the_run_with_2(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["identify", "--span-nm", "4000", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "the largest span whose extra line fits is 3000 nm" in err
    assert err.count("\n") == 1 and not out.exists()
