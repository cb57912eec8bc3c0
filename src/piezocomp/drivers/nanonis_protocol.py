"""The Nanonis TCP framing, both ways: requests and replies, and a checked client connection.

From the vendor's documented TCP programming interface (SPECS, "TCP Protocol - Nanonis SPM
Controller"): every message is a 40-byte header then a big-endian body.

Header: the command name in 32 bytes (UTF-8, NUL-padded, e.g. ``FolMe.XYPosSet``), the body
size (int32), the send-response flag (uint16; a request asks for a reply with 1) and 2 bytes
of padding. A reply repeats the command name and carries, after its return values, the
error section: status (uint32, 0: no error), description size (int32) and the description.

Bodies are described here by a tuple of codes: ``"H"`` uint16, ``"I"`` uint32, ``"i"``
int32, ``"f"`` float32, ``"d"`` float64, ``"str"`` (int32 byte count then UTF-8 bytes),
``"[i]"`` (int32 count then int32 items) and ``"[[f]]"`` (int32 rows, int32 columns, then
float32 items row by row). Everything sent is in the controller's units (metres, volts,
seconds); the conversion to nm happens in the backend (:mod:`.nanonis`).

Written for piezocomp from the protocol's description, not copied from any client: the
published Python clients (``nanonis-spm``, ``nanonisTCP``) are not wrapped because their
transport does not meet the backend's safety contract (see ``docs/instruments.md``).
:class:`NanonisConnection` reads exactly the bytes a header announces, under a timeout,
checks the reply's command name, size and error section, and closes itself for good after
any transport failure, so a late reply can never be taken for the answer to a later call.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "HEADER_SIZE",
    "MAX_BODY_BYTES",
    "NanonisConnection",
    "NanonisError",
    "NanonisReplyError",
    "decode_header",
    "decode_values",
    "encode_header",
    "encode_reply",
    "encode_request",
    "encode_values",
    "parse_reply",
    "recv_exact",
]

HEADER_SIZE = 40
"""Bytes of every message's header: name (32), body size (4), response flag (2), padding (2)."""

MAX_BODY_BYTES = 64 * 1024 * 1024
"""Largest body taken from the controller (a 4096 x 4096 float32 frame and its framing)."""

_SCALARS = {"H": ">H", "I": ">I", "i": ">i", "f": ">f", "d": ">d"}


class NanonisError(OSError):
    """A failure talking to the controller: no reply in time, the connection dropped, a
    malformed reply. The connection is closed after it; reconnect to go on."""


class NanonisReplyError(NanonisError):
    """The controller answered with its error flag set (the command was refused); the
    connection stays usable."""


def encode_header(name: str, body_size: int, respond: bool = True) -> bytes:
    """The 40-byte header of a message named ``name`` with a body of ``body_size`` bytes."""
    raw = name.encode("utf-8")
    if not 0 < len(raw) <= 32:
        raise ValueError(f"a Nanonis command name takes 1-32 bytes. Got {name!r}.")
    if not 0 <= body_size <= MAX_BODY_BYTES:
        raise ValueError(f"body size must be in 0-{MAX_BODY_BYTES}. Got {body_size}.")
    return raw.ljust(32, b"\0") + struct.pack(">iHH", body_size, 1 if respond else 0, 0)


def decode_header(header: bytes) -> tuple[str, int, bool]:
    """``(name, body_size, respond)`` of a 40-byte header; ``ValueError`` if malformed."""
    if len(header) != HEADER_SIZE:
        raise ValueError(f"a header has {HEADER_SIZE} bytes. Got {len(header)}.")
    try:
        name = header[:32].rstrip(b"\0").decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("the header's command name is not UTF-8.") from None
    size, respond, _ = struct.unpack(">iHH", header[32:])
    if not name or "\0" in name or not name.isprintable():
        raise ValueError(f"the header's command name is malformed: {name!r}.")
    if not 0 <= size <= MAX_BODY_BYTES:
        raise ValueError(f"the header announces a body of {size} bytes (0-{MAX_BODY_BYTES}).")
    return name, size, bool(respond)


def encode_values(codes: Sequence[str], values: Sequence[Any]) -> bytes:
    """The big-endian body of ``values`` typed by ``codes`` (see the module docstring)."""
    if len(codes) != len(values):
        raise ValueError(f"{len(codes)} codes for {len(values)} values.")
    out = bytearray()
    for code, v in zip(codes, values, strict=True):
        if code in _SCALARS:
            out += struct.pack(_SCALARS[code], v)
        elif code == "str":
            raw = str(v).encode("utf-8")
            out += struct.pack(">i", len(raw)) + raw
        elif code == "[i]":
            items = np.asarray(v, dtype=">i4").ravel()
            out += struct.pack(">i", items.size) + items.tobytes()
        elif code == "[[f]]":
            a = np.asarray(v, dtype=">f4")
            if a.ndim != 2:
                raise ValueError(f"a [[f]] value must be 2-D. Got shape {a.shape}.")
            out += struct.pack(">ii", *a.shape) + a.tobytes()
        else:
            raise ValueError(f"unknown body code {code!r}.")
    return bytes(out)


def decode_values(codes: Sequence[str], body: bytes, offset: int = 0) -> tuple[list[Any], int]:
    """The values typed by ``codes`` read from ``body`` at ``offset``, and the offset after
    them; ``ValueError`` if the body is too short or a count is negative."""
    out: list[Any] = []
    pos = offset

    def take(n: int) -> bytes:
        nonlocal pos
        if n < 0 or pos + n > len(body):
            raise ValueError(
                f"the body ends at byte {len(body)}; {n} more bytes were due at byte {pos}."
            )
        chunk = body[pos : pos + n]
        pos += n
        return chunk

    for code in codes:
        if code in _SCALARS:
            fmt = _SCALARS[code]
            out.append(struct.unpack(fmt, take(struct.calcsize(fmt)))[0])
        elif code == "str":
            (n,) = struct.unpack(">i", take(4))
            try:
                out.append(take(n).decode("utf-8"))
            except UnicodeDecodeError:
                raise ValueError("a string of the body is not UTF-8.") from None
        elif code == "[i]":
            (n,) = struct.unpack(">i", take(4))
            out.append(np.frombuffer(take(4 * n), dtype=">i4").astype(np.int64))
        elif code == "[[f]]":
            rows, cols = struct.unpack(">ii", take(8))
            if rows < 0 or cols < 0:
                raise ValueError(f"a 2-D array of {rows} x {cols} items.")
            data = np.frombuffer(take(4 * rows * cols), dtype=">f4")
            out.append(data.astype(np.float64).reshape(rows, cols))
        else:
            raise ValueError(f"unknown body code {code!r}.")
    return out, pos


def encode_request(name: str, codes: Sequence[str] = (), values: Sequence[Any] = ()) -> bytes:
    """A whole request (header and body) asking for a reply."""
    body = encode_values(codes, values)
    return encode_header(name, len(body)) + body


def encode_reply(
    name: str,
    codes: Sequence[str] = (),
    values: Sequence[Any] = (),
    *,
    error_status: int = 0,
    error_text: str = "",
) -> bytes:
    """A whole reply: the return values then the error section."""
    err = error_text.encode("utf-8")
    body = encode_values(codes, values) + struct.pack(">Ii", error_status, len(err)) + err
    return encode_header(name, len(body), respond=False) + body


def parse_reply(codes: Sequence[str], body: bytes) -> tuple[list[Any], int, str]:
    """``(values, error_status, error_text)`` of a reply body; ``ValueError`` unless the
    body is exactly the values, then the error section."""
    values, pos = decode_values(codes, body)
    (status, size), pos = decode_values(("I", "i"), body, pos)
    if size < 0 or pos + size != len(body):
        raise ValueError(
            f"the error section announces {size} bytes of description; {len(body) - pos} "
            "bytes are left in the body."
        )
    try:
        text = body[pos:].decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("the error description is not UTF-8.") from None
    return values, int(status), text


def recv_exact(sock: socket.socket, n: int) -> bytes:
    """Exactly ``n`` bytes from ``sock``; ``ConnectionError`` if it closes first (the
    socket's timeout raises ``TimeoutError``)."""
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(min(n - len(buf), 1 << 20))
        if not chunk:
            raise ConnectionError(f"closed after {len(buf)} of {n} bytes")
        buf += chunk
    return bytes(buf)


class NanonisConnection:
    """A client connection to a Nanonis controller's TCP programming interface.

    Parameters
    ----------
    host : str
        The controller's address (the Nanonis PC).
    port : int
        One of the ports the controller listens on (Nanonis: File > Settings > TCP
        Programming Interface; 6501 by default).
    timeout_s : float
        Longest wait for the connection and for each reply, s; a slower reply is a failure.

    Notes
    -----
    One call at a time: :meth:`call` sends a request and reads its whole reply before it
    returns. After a transport failure (timeout, closed connection, malformed reply) the
    connection is closed and every later call is refused.
    """

    def __init__(self, host: str, port: int, *, timeout_s: float = 2.0) -> None:
        if not (isinstance(port, int) and 0 < port < 65536):
            raise ValueError(f"port must be an integer in 1-65535. Got {port!r}.")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0. Got {timeout_s}.")
        self.address = f"{host}:{port}"
        self.timeout_s = float(timeout_s)
        self.closed_because = ""
        try:
            self._sock: socket.socket | None = socket.create_connection(
                (host, port), timeout=timeout_s
            )
        except OSError as exc:
            raise NanonisError(
                f"cannot connect to nanonis://{self.address}: {exc.strerror or exc}"
            ) from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def call(
        self,
        name: str,
        codes: Sequence[str] = (),
        values: Sequence[Any] = (),
        reply: Sequence[str] = (),
        *,
        timeout_s: float | None = None,
    ) -> list[Any]:
        """Send command ``name`` with ``values`` typed by ``codes``; return the reply's
        values typed by ``reply`` (waiting ``timeout_s`` for it, default :attr:`timeout_s`).

        Raises
        ------
        NanonisReplyError
            The controller set its error flag (the connection stays open).
        NanonisError
            No reply within ``timeout_s``, the connection closed, or a malformed reply (the
            connection is then closed).
        """
        if self._sock is None:
            raise NanonisError(
                f"the connection to nanonis://{self.address} was closed ({self.closed_because})"
                "; reconnect"
            )
        message = encode_request(name, codes, values)
        wait = self.timeout_s if timeout_s is None else float(timeout_s)
        try:
            self._sock.settimeout(wait)
            self._sock.sendall(message)
            got, size, _ = decode_header(recv_exact(self._sock, HEADER_SIZE))
            body = recv_exact(self._sock, size)
            if got != name:
                raise ValueError(f"the reply is to {got!r}, not to {name!r}")
            out, status, text = parse_reply(reply, body)
        except TimeoutError:
            raise self._fail(f"no reply to {name} within {wait:g} s") from None
        except (ConnectionError, OSError) as exc:
            raise self._fail(f"the connection dropped during {name} ({exc})") from None
        except (ValueError, struct.error) as exc:
            raise self._fail(f"malformed reply to {name}: {exc}") from None
        if status != 0:
            raise NanonisReplyError(
                f"the controller refused {name} (error {status}: {text.strip() or 'no text'})"
            )
        return out

    def _fail(self, why: str) -> NanonisError:
        self.close(why)
        return NanonisError(f"nanonis://{self.address}: {why}; the connection is closed")

    def close(self, why: str = "closed by the client") -> None:
        """Close the connection (later calls are refused, naming ``why``)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            self.closed_because = why

    @property
    def closed(self) -> bool:
        """Whether the connection is closed."""
        return self._sock is None
