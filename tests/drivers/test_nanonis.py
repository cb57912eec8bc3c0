"""The Nanonis backend over real loopback sockets against its emulator (virtual AFM behind).

Every test runs its own emulator on 127.0.0.1 with a free port, in a thread that stops with
the test; paths are short and timeouts small, so each test takes well under a second or two.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from piezocomp.drivers.nanonis import NanonisInstrument, TimingError, parse_address
from piezocomp.drivers.nanonis_emulator import Fault, NanonisEmulator
from piezocomp.drivers.nanonis_protocol import (
    HEADER_SIZE,
    NanonisError,
    NanonisReplyError,
    decode_header,
    decode_values,
    encode_reply,
    encode_request,
    parse_reply,
)
from piezocomp.virtual_afm import VirtualAFM

T = 0.008


def _afm() -> VirtualAFM:
    return VirtualAFM.from_preset("cpr5-nodrift", seed=1, sample_period_s=T)


@pytest.fixture
def emulator():
    with NanonisEmulator(_afm()) as emu:
        yield emu


def _connect(emu: NanonisEmulator, **kw) -> NanonisInstrument:
    opts = {"sample_period_s": T, "max_speed_nm_per_s": emu.afm.max_speed_nm_per_s,
            "speedup": 50.0, "emulator": True, "timing": "flag", "timeout_s": 0.5}  # fmt: skip
    opts.update(kw)
    return NanonisInstrument.connect(emu.url, **opts)


def _ramp(n: int = 40, to_nm: float = 80.0) -> np.ndarray:
    return np.column_stack([np.linspace(to_nm / n, to_nm, n), np.zeros(n)])


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text
    return text


# ----------------------------------------------------------------- framing
def test_nanonis_framing_round_trip_every_code():
    codes = ("H", "I", "i", "f", "d", "str", "[i]", "[[f]]")
    values = (7, 2**32 - 1, -5, 1.5, 1e-9, "Z (m)", [3, 30], np.arange(6.0).reshape(2, 3))
    msg = encode_request("Scan.FrameDataGrab", codes, values)
    name, size, respond = decode_header(msg[:HEADER_SIZE])
    assert (name, size, respond) == ("Scan.FrameDataGrab", len(msg) - HEADER_SIZE, True)
    assert msg[32:36] == struct.pack(">i", size)  # big-endian body size after the name
    got, end = decode_values(codes, msg[HEADER_SIZE:])
    assert end == size
    assert got[:6] == [7, 2**32 - 1, -5, 1.5, 1e-9, "Z (m)"]
    assert got[6].tolist() == [3, 30]
    np.testing.assert_array_equal(got[7], values[7])


def test_nanonis_reply_error_section_and_malformed_bodies():
    reply = encode_reply("ZCtrl.ZPosGet", ("f",), (2.5e-8,))
    name, _, respond = decode_header(reply[:HEADER_SIZE])
    assert (name, respond) == ("ZCtrl.ZPosGet", False)
    values, status, text = parse_reply(("f",), reply[HEADER_SIZE:])
    assert status == 0 and text == "" and values[0] == pytest.approx(2.5e-8, rel=1e-7)
    err = encode_reply("FolMe.XYPosSet", error_status=1, error_text="out of range")
    assert parse_reply((), err[HEADER_SIZE:])[1:] == (1, "out of range")
    body = reply[HEADER_SIZE:]
    with pytest.raises(ValueError, match="body ends"):
        parse_reply(("f",), body[:5])
    with pytest.raises(ValueError, match="error section"):
        parse_reply(("f",), body + b"\x00")
    with pytest.raises(ValueError, match="announces a body"):
        decode_header(b"X".ljust(32, b"\0") + struct.pack(">iHH", -1, 0, 0))


def test_nanonis_address_and_fault_parsing():
    assert parse_address("nanonis://127.0.0.1:6501") == ("127.0.0.1", 6501)
    for bad in ("127.0.0.1:6501", "nanonis://host", "nanonis://h:99999", "tcp://h:1"):
        with pytest.raises(ValueError, match="nanonis://HOST:PORT"):
            parse_address(bad)
    assert Fault.parse("drop@200") == Fault("drop", "FolMe.XYPosSet", 200)
    assert Fault.parse("error@3:ZCtrl.OnOffSet") == Fault("error", "ZCtrl.OnOffSet", 3)
    with pytest.raises(ValueError, match="fault kind"):
        Fault.parse("explode")
    with pytest.raises(ValueError, match="loopback"):
        NanonisEmulator(_afm(), host="0.0.0.0")


# ----------------------------------------------------------------- a session
def test_nanonis_streamed_path_matches_the_virtual_afm_and_reports_timing(emulator):
    inst = _connect(emulator)
    c = inst.controller
    assert c.range_nm == (5000.0, 5000.0) and not c.drift_ramp_on
    u = _ramp()
    rec = inst.run(u)
    direct = _afm().run(u)  # the emulator's clock is the set-point stream: same samples
    np.testing.assert_allclose(rec.height_nm, direct.height_nm, atol=1e-5)  # float32 Z
    assert inst.command_nm == tuple(u[-1]) == emulator.afm.command_nm
    assert rec.timing is not None and rec.timing.sent_s.size == u.shape[0]
    assert rec.timing.period_s == T and rec.timing.tolerance_s == pytest.approx(0.5 * T)
    assert "samples at T = 0.008 s" in rec.timing.summary()
    np.testing.assert_array_equal(rec.t_s, rec.timing.sent_s)
    inst.close()


def test_nanonis_timing_within_tolerance_at_the_real_period(emulator):
    inst = _connect(emulator, sample_period_s=0.02, speedup=1.0, timing_tolerance=1.0)
    emulator.afm._T = 0.02  # the emulator's scanner at the same period
    rec = inst.run(_ramp(15, 20.0))
    assert rec.timing is not None and rec.timing.ok, rec.timing.summary()
    assert rec.timing.max_deviation_s < 0.02
    inst.close()


def test_nanonis_timing_broken_path_is_flagged_or_refused(emulator):
    inst = _connect(emulator, timing="raise", timeout_s=1.0)
    emulator.inject(Fault("slow", after=10, delay_s=0.2))  # set-point 11 answers 0.2 s late
    with pytest.raises(TimingError, match="broke the model's assumption") as info:
        inst.run(_ramp(20, 20.0))
    rec = info.value.record
    assert rec.timing is not None and not rec.timing.ok
    assert rec.timing.late_samples >= 1 and rec.timing.max_deviation_s > 0.1 * 50 * 0.5
    assert "not to be used" in _one_line(info.value)
    assert "stopped at a streamed path" in str(info.value) and "--timing flag" in str(info.value)
    emulator.inject(Fault("slow", after=5, delay_s=0.2))  # a move names itself
    with pytest.raises(TimingError, match=r"stopped at a move to \(60, 0\) nm"):
        inst.move_to(60.0, 0.0, 100.0)
    inst.close()


def test_nanonis_range_and_slew_checked_before_sending(emulator):
    inst = _connect(emulator)
    before = emulator.set_points
    with pytest.raises(ValueError, match="outside the scanner range"):
        inst.move_to(3000.0, 0.0, 100.0)
    fast = np.array([[0.0, 0.0], [500.0, 0.0]])  # 500 nm in one period
    with pytest.raises(ValueError, match="command x"):
        inst.run(fast)
    with pytest.raises(ValueError, match="max_speed_nm_per_s"):
        inst.move_to(10.0, 0.0, 1e9)
    assert emulator.set_points == before
    inst.close()


# ----------------------------------------------------------------- faults
@pytest.mark.parametrize(
    ("kind", "message", "served"),
    [
        ("slow", "no reply to FolMe.XYPosSet within 0.2 s", 6),
        ("drop", "connection dropped during FolMe.XYPosSet", 5),
        ("malformed", "malformed reply to FolMe.XYPosSet", 6),
        ("error", "the controller refused FolMe.XYPosSet", 5),
    ],
)
def test_nanonis_fault_stops_the_path_where_it_was(emulator, kind, message, served):
    inst = _connect(emulator, timeout_s=0.2)
    emulator.inject(Fault(kind, after=5, delay_s=0.6))
    u = _ramp()
    with pytest.raises(NanonisError) as info:
        inst.run(u)
    text = _one_line(info.value)
    assert message in text and "stopped after 5 of 40 set-points" in text
    assert "(10.000, 0.000) nm" in text and "nothing more was sent" in text
    assert inst.command_nm == tuple(u[4])
    emulator._stop.wait(0.7 if kind == "slow" else 0.05)  # a late reply has been served
    assert emulator.set_points == served  # never a half-sent path that goes on
    np.testing.assert_array_equal(emulator.afm.command_nm, u[served - 1])
    if kind == "error":  # the connection still answers: the path was stopped, not closed
        assert isinstance(info.value, NanonisReplyError)
        assert emulator.calls("FolMe.Stop") == 1
        assert inst.run(u[5:8]).height_nm.size == 3
    else:
        with pytest.raises(NanonisError, match="closed"):
            inst.wait(0.1)
    inst.close()


def test_nanonis_push_restores_z_feedback_after_a_failure(emulator):
    inst = _connect(emulator)
    emulator.inject(Fault("error", after=3))
    with pytest.raises(NanonisReplyError, match="stopped after 3 of") as info:
        inst.push(50.0, 0.0, 500.0)
    assert "Z feedback" not in str(info.value)  # switched back on: nothing to report
    assert emulator.z_feedback is True
    assert emulator.calls("ZCtrl.OnOffSet") == 2  # off, then on again
    rec = inst.push(50.0, 0.0, 500.0)  # a push that works leaves it on too
    assert emulator.z_feedback is True and rec.timing is not None
    inst.close()


def test_nanonis_push_interrupted_by_ctrl_c_restores_z_feedback(emulator, monkeypatch):
    inst = _connect(emulator)
    real = inst._conn.call
    count = {"set": 0}

    def call(name, *args, **kw):
        if name == "FolMe.XYPosSet":
            count["set"] += 1
            if count["set"] == 4:
                raise KeyboardInterrupt
        return real(name, *args, **kw)

    monkeypatch.setattr(inst._conn, "call", call)
    with pytest.raises(KeyboardInterrupt) as info:
        inst.push(50.0, 0.0, 500.0)
    assert any("stopped after 3 of" in note for note in info.value.__notes__)
    assert emulator.z_feedback is True and emulator.set_points == 3
    inst.close()


def test_nanonis_push_reports_z_feedback_it_could_not_restore(emulator):
    inst = _connect(emulator, timeout_s=0.2)
    emulator.inject(Fault("drop", after=2))
    with pytest.raises(NanonisError) as info:
        inst.push(50.0, 0.0, 500.0)
    text = _one_line(info.value)
    assert "Z feedback could NOT be switched back on" in text and "at the controller" in text
    inst.close()


# ----------------------------------------------------------------- controller state
def test_nanonis_connect_checks_z_feedback_and_switches_the_drift_ramp_off():
    with NanonisEmulator(_afm()) as emu:
        emu.z_feedback = False
        with pytest.raises(ValueError, match="Z feedback is off"):
            _connect(emu)
        emu.z_feedback = True
        emu.drift_ramp_on, emu._ramp_m_s = True, (1e-10, -2e-10, 0.0)
        inst = _connect(emu)
        assert inst.controller.drift_ramp_was_on and not inst.controller.drift_ramp_on
        assert inst.controller.drift_ramp_nm_per_s == pytest.approx((0.1, -0.2))
        assert not emu.drift_ramp_on and "switched off" in inst.controller.summary()
        inst.close()
        emu.drift_ramp_on = True
        kept = _connect(emu, drift_ramp="keep")
        assert kept.controller.drift_ramp_on and emu.drift_ramp_on
        kept.close()


def test_nanonis_images_by_the_controller_and_streamed(emulator):
    inst = _connect(emulator)
    img = inst.scan_image((0.0, 0.0), 200.0, 16, 5.0)  # the controller's own scan
    assert emulator.calls("Scan.Action") == 1 and img.forward_nm.shape == (16, 16)
    assert np.all(np.isfinite(img.forward_nm)) and np.all(np.isfinite(img.backward_nm))
    img2 = inst.scan_image((0.0, 0.0), 200.0, 6, 5.0, fast_axis="y")  # streamed
    assert emulator.calls("Scan.Action") == 1 and img2.forward_nm.shape == (6, 6)
    inst.close()


def test_nanonis_identify_instrument_flags_checked_in_one_line(tmp_path, capsys):
    from piezocomp.cli import main

    out = str(tmp_path / "run")
    assert main(["identify", "--instrument", "nanonis://127.0.0.1:1", "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "needs --max-speed-nm-per-s" in err
    args = ["identify", "--instrument", "nanonis://127.0.0.1:1", "--max-speed-nm-per-s", "100"]
    assert main([*args, "--out", out]) == 2
    assert "--reference none" in capsys.readouterr().err
    assert main(["identify", "--speedup", "2", "--out", out]) == 2
    assert "--speedup goes with --instrument" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
