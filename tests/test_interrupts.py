"""Commands stopped by Ctrl-C (``SIGINT``) or a job scheduler (``SIGTERM``) in a real
subprocess, while they write their files: one line, exit 128 + the signal, no temporary file
left, earlier outputs unchanged, no folder that looks complete."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import piezocomp
from piezocomp._atomic import PAUSE_ENV
from piezocomp.model import ModelState, ScannerModel, simulate

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

SRC = str(Path(piezocomp.__file__).resolve().parents[1])
"""The package's source folder, so the subprocess runs this code, not an installed copy."""

WAIT_S = 60.0
"""Longest wait for a command to reach its writing, or to exit once signalled."""


def start(*args: str | Path, cwd: Path) -> subprocess.Popen[str]:
    # the output group waits before its commit: the signal, sent once a file is staged,
    # arrives while the files are still staged however loaded the machine is
    env = {**os.environ, "PYTHONPATH": SRC, PAUSE_ENV: "3"}
    env.pop("PIEZOCOMP_DEBUG", None)
    cmd = [sys.executable, "-m", "piezocomp.cli", *map(str, args)]
    # start_new_session: the signal goes to this process only, as a scheduler's would;
    # SIGINT back to its default: a test suite started in the background by a shell inherits
    # it ignored, and so would the command, which then never sees the Ctrl-C
    return subprocess.Popen(
        cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True, preexec_fn=_default_sigint,
    )  # fmt: skip


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def temporaries(folder: Path, name: str = "*") -> list[Path]:
    """The temporary files under ``folder`` (of the file ``name``)."""
    return sorted(p for p in folder.rglob(f".{name}.*.tmp"))


def signal_while_writing(
    proc: subprocess.Popen[str], folder: Path, name: str, sig: int
) -> tuple[int, str]:
    """Send ``sig`` as soon as the temporary file of ``name`` appears under ``folder`` (files
    written before it are done); the exit status and stderr."""
    deadline = time.monotonic() + WAIT_S
    while not temporaries(folder, name):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            _, err = proc.communicate()
            pytest.fail(f"no temporary file appeared before the command ended: {err}")
        time.sleep(0.0005)  # the window of a small file is a few milliseconds
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=WAIT_S)
    return proc.returncode, err


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_sigterm_while_an_image_is_written_leaves_the_earlier_run_as_it_was(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "image.npz").write_bytes(b"the earlier run")  # written before forward.png
    (out / "notes.txt").write_text("mine")
    proc = start("simulate-afm", "--out", out, "--pixels", "128", "--seed", "3", cwd=tmp_path)
    code, err = signal_while_writing(proc, out, "forward.png", signal.SIGTERM)
    assert code == 128 + signal.SIGTERM
    assert one_line(err) == "piezocomp simulate-afm: interrupted (SIGTERM); nothing written"
    assert temporaries(tmp_path) == []
    assert sorted(p.name for p in out.iterdir()) == ["image.npz", "notes.txt"]
    assert (out / "image.npz").read_bytes() == b"the earlier run"


def test_ctrl_c_while_an_image_is_written_removes_the_new_folder(tmp_path):
    out = tmp_path / "new" / "out"
    proc = start("simulate-afm", "--out", out, "--pixels", "128", cwd=tmp_path)
    code, err = signal_while_writing(proc, tmp_path, "image.npz", signal.SIGINT)
    assert code == 130
    assert one_line(err) == "piezocomp simulate-afm: interrupted; nothing written"
    assert list(tmp_path.iterdir()) == []  # no temporary file, no empty folder


def _record(path: Path, n: int = 1500) -> None:
    T = 0.01
    truth = ScannerModel(offset_nm=-20.0, gain=0.6, thresholds_nm=[60.0, 150.0],
                         weights=[0.2, 0.1], creep_time_constants_s=[1.0],
                         creep_gains=[0.1])  # fmt: skip
    t = np.arange(n) * T
    u = 300.0 + 400.0 * np.sin(2 * np.pi * 0.5 * t) * (0.3 + 0.7 * np.abs(np.sin(0.3 * t)))
    y, _ = simulate(truth, u, T, ModelState.at_rest(truth, u[0]))
    rows = "\n".join(",".join(repr(float(v)) for v in r) for r in zip(t, u, y, strict=True))
    path.write_text("t_s,u_nm,y_nm\n" + rows + "\n")


def test_ctrl_c_while_a_fit_writes_changes_no_output(tmp_path):
    """The model, its summary and its figure are one set: all are written, or none."""
    _record(tmp_path / "rec.csv")
    (tmp_path / "model.json").write_text("the earlier model")
    proc = start("fit", "--input", "rec.csv", "--output", "model.json", "--n-play", "2",
                 "--n-creep", "1", "--summary", "summary.json", "--figures", "figs",
                 cwd=tmp_path)  # fmt: skip
    # the first of the set's files staged (the figure), the others still to come
    code, err = signal_while_writing(proc, tmp_path, "*", signal.SIGINT)
    assert code == 130
    assert one_line(err) == "piezocomp fit: interrupted; nothing written"
    assert temporaries(tmp_path) == []
    assert (tmp_path / "model.json").read_text() == "the earlier model"
    assert not (tmp_path / "summary.json").exists()
    assert not (tmp_path / "figs").exists()


def test_a_checkpoint_keeps_the_parts_done_when_a_later_one_is_interrupted(tmp_path):
    """``reproduce --seeds``: each sample's files are put in place when it is done; an
    interrupt in the next one removes only that one's."""
    from piezocomp._atomic import atomic_write_text, commit_so_far, output_group

    with pytest.raises(KeyboardInterrupt), output_group() as group:
        atomic_write_text(tmp_path / "seed-1" / "results.json", "{}\n")
        commit_so_far()
        atomic_write_text(tmp_path / "seed-2" / "results.json", "{}\n")
        raise KeyboardInterrupt
    assert (tmp_path / "seed-1" / "results.json").read_text() == "{}\n"
    assert not (tmp_path / "seed-2").exists()
    assert group.written == [tmp_path / "seed-1" / "results.json"]
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["results.json", "seed-1"]
