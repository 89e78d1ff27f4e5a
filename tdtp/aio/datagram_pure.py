"""The datagram layer's engine in plain Python: the same interface as the compiled
``tdtp.aio._datagram.Engine``, over ``socket.recvfrom`` / ``recvmsg`` / ``sendto``.

It runs where the C extension was not built (no C compiler, ``TDTP_PURE_BUILD=1``) or is switched off
(``TDTP_PURE_PYTHON=1``), and the tests run both. One wake-up still delivers a whole batch in one
callback; what it cannot save is the system call per datagram (Python's ``socket`` has no
``recvmmsg``/``sendmmsg``).
"""

from __future__ import annotations

import errno
import socket
import struct
from collections.abc import Callable
from typing import Final

from tdtp.errors import ArgumentTypeError, DatagramLayerClosedError, InvalidArgumentError
from tdtp.session.events import Address

__all__ = ["MAX_BATCH", "MAX_BUFFER", "MAX_TOTAL", "MIN_BUFFER", "PureEngine"]

MAX_BATCH: Final = 1024
MIN_BUFFER: Final = 64
MAX_BUFFER: Final = 65536
MAX_TOTAL: Final = 16 * 1024 * 1024
_DEFAULT_ROUNDS: Final = 16
_CONTROL_SPACE: Final = 128
_SO_TIMESTAMPNS: Final = getattr(socket, "SO_TIMESTAMPNS", 35)
_IPV6_TCLASS: Final = getattr(socket, "IPV6_TCLASS", 67)
_TIMESPEC: Final = struct.Struct("@qq")
_AGAIN: Final = (errno.EAGAIN, errno.EWOULDBLOCK)

BatchCallback = Callable[[list[bytes], list[Address], list[int] | None, list[int] | None], None]
ErrorCallback = Callable[[OSError], None]
BlockedCallback = Callable[[list[tuple[bytes, Address | None]]], None]

_COUNTERS: Final = (
    "datagrams_received",
    "bytes_received",
    "batches_received",
    "recv_calls",
    "truncated",
    "receive_errors",
    "port_unreachable",
    "datagrams_sent",
    "bytes_sent",
    "send_calls",
    "send_errors",
    "too_big",
    "no_buffer",
    "blocked",
)


def check_parameters(family: int, batch: int, buffer_size: int) -> None:
    """The bounds both engines enforce (:class:`~tdtp.InvalidArgumentError` names the one broken)."""
    if family not in (socket.AF_INET, socket.AF_INET6):
        raise InvalidArgumentError(f"family must be AF_INET or AF_INET6, got {family!r}")
    if isinstance(batch, bool) or not isinstance(batch, int) or not 1 <= batch <= MAX_BATCH:
        raise InvalidArgumentError(f"batch must be in 1..{MAX_BATCH}, got {batch!r}")
    if (
        isinstance(buffer_size, bool)
        or not isinstance(buffer_size, int)
        or not MIN_BUFFER <= buffer_size <= MAX_BUFFER
    ):
        raise InvalidArgumentError(
            f"buffer_size must be in {MIN_BUFFER}..{MAX_BUFFER}, got {buffer_size!r}"
        )
    if batch * buffer_size > MAX_TOTAL:
        raise InvalidArgumentError(
            f"batch x buffer_size must be at most {MAX_TOTAL} bytes, got {batch} x {buffer_size}"
        )


class PureEngine:
    """Batched receive and send over a borrowed non-blocking UDP socket, one system call per
    datagram. See :mod:`tdtp.aio.datagram` for what each method promises."""

    def __init__(
        self,
        sock: socket.socket,
        family: int,
        batch: int,
        buffer_size: int,
        on_batch: BatchCallback,
        *,
        on_error: ErrorCallback | None = None,
        on_blocked: BlockedCallback | None = None,
        timestamps: bool = False,
        traffic_class: bool = False,
    ) -> None:
        check_parameters(family, batch, buffer_size)
        if not callable(on_batch) or any(
            cb is not None and not callable(cb) for cb in (on_error, on_blocked)
        ):
            raise ArgumentTypeError("on_batch, on_error and on_blocked must be callable")
        self._sock = sock
        self.family = family
        self.batch = batch
        self.buffer_size = buffer_size
        self.rounds = _DEFAULT_ROUNDS
        self.paused = 0
        self._closed = False
        self._on_batch = on_batch
        self._on_error = on_error
        self._on_blocked = on_blocked
        self._timestamps = timestamps
        self._tclass = traffic_class
        self._control = _CONTROL_SPACE if (timestamps or traffic_class) else 0
        self._c = dict.fromkeys(_COUNTERS, 0)

    # ------------------------------------------------------------------ receiving

    def drain(self) -> int:
        if self._closed:
            return 0
        delivered = 0
        for _ in range(self.rounds):
            n = self._one_batch()
            if n < 0:
                break
            delivered += n
            if n < self.batch or self._closed:
                break
        return delivered

    def _one_batch(self) -> int:
        """Receive up to ``batch`` datagrams and deliver them; how many were read (truncated ones
        included), or -1 when nothing was."""
        sock, c, size = self._sock, self._c, self.buffer_size
        datas: list[bytes] = []
        addrs: list[Address] = []
        stamps: list[int] | None = [] if self._timestamps else None
        classes: list[int] | None = [] if self._tclass else None
        control = self._control
        read = 0
        while read < self.batch:
            c["recv_calls"] += 1
            try:
                if control:
                    data, ancdata, flags, addr = sock.recvmsg(size, control)
                    truncated = bool(flags & socket.MSG_TRUNC)
                else:
                    data, addr = sock.recvfrom(size + 1)
                    truncated = len(data) > size
                    ancdata = []
            except InterruptedError:
                continue
            except BlockingIOError:
                break
            except OSError as exc:
                self._report(exc, sending=False)
                if isinstance(exc, ConnectionRefusedError):
                    continue  # reporting cleared the pending ICMP error: read on
                break
            read += 1
            if truncated:
                c["truncated"] += 1
                continue
            datas.append(data)
            addrs.append(addr)
            c["datagrams_received"] += 1
            c["bytes_received"] += len(data)
            if control:
                stamp, tos = self._ancillary(ancdata)
                if stamps is not None:
                    stamps.append(stamp)
                if classes is not None:
                    classes.append(tos)
        if datas:
            c["batches_received"] += 1
            self._on_batch(datas, addrs, stamps, classes)
        return read if read else -1

    @staticmethod
    def _ancillary(ancdata: list[tuple[int, int, bytes]]) -> tuple[int, int]:
        stamp, tos = -1, -1
        for level, kind, value in ancdata:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                sec, nsec = _TIMESPEC.unpack_from(value)
                stamp = sec * 1_000_000_000 + nsec
            elif level == socket.IPPROTO_IP and kind == socket.IP_TOS and value:
                tos = value[0]
            elif level == socket.IPPROTO_IPV6 and kind == _IPV6_TCLASS and value:
                tos = int.from_bytes(value[:4], "little") & 0xFF
        return stamp, tos

    # ------------------------------------------------------------------ sending

    def send(self, data: bytes, addr: Address | None = None, /) -> bool:
        if self._closed:
            raise DatagramLayerClosedError("the datagram layer is closed")
        if self.paused:
            self._hand_back([(data, addr)])
            return False
        return self._send_one(data, addr) > 0

    def send_batch(self, items: list[tuple[bytes, Address | None]]) -> int:
        if self._closed:
            raise DatagramLayerClosedError("the datagram layer is closed")
        if not isinstance(items, list):
            raise ArgumentTypeError(
                f"send_batch takes a list of (data, addr) pairs, got {type(items).__name__}"
            )
        if self.paused:
            self._hand_back(items)
            return 0
        sent = 0
        for i, item in enumerate(items):
            if not isinstance(item, tuple) or len(item) != 2:
                raise ArgumentTypeError(f"send_batch items are (data, addr) pairs, got {item!r}")
            outcome = self._send_one(item[0], item[1])
            if outcome < 0:
                self._hand_back(items[i:])
                break
            sent += outcome
        return sent

    def _send_one(self, data: bytes, addr: Address | None) -> int:
        """1 sent, 0 lost (counted), -1 the send buffer is full."""
        c = self._c
        if not isinstance(data, bytes | bytearray | memoryview):
            raise ArgumentTypeError(f"a datagram must be bytes-like, got {type(data).__name__}")
        while True:
            c["send_calls"] += 1
            try:
                if addr is None:
                    self._sock.send(data)
                else:
                    self._sock.sendto(data, self._destination(addr))
            except InterruptedError:
                continue
            except BlockingIOError:
                return -1
            except OSError as exc:
                self._report(exc, sending=True)
                return 0
            c["datagrams_sent"] += 1
            c["bytes_sent"] += len(data)
            return 1

    def _destination(self, addr: Address) -> Address:
        if not isinstance(addr, tuple) or not 2 <= len(addr) <= 4:
            raise ArgumentTypeError(
                f"an address must be a (host, port) tuple with a numeric host, got {addr!r}"
            )
        host = addr[0]
        if not isinstance(host, str) or not isinstance(addr[1], int):
            raise ArgumentTypeError(
                f"an address must be a (host: str, port: int) tuple, got {addr!r}"
            )
        bare = host.partition("%")[0]
        for family in (socket.AF_INET, socket.AF_INET6):
            try:
                socket.inet_pton(family, bare)
            except OSError:
                continue
            if family == socket.AF_INET6 and self.family == socket.AF_INET:
                raise InvalidArgumentError(f"an IPv6 destination {addr!r} for an IPv4 socket")
            if family == socket.AF_INET and self.family == socket.AF_INET6:
                return ("::ffff:" + host, addr[1])
            return addr
        raise InvalidArgumentError(
            f"the host of {addr!r} is not a numeric IPv4 or IPv6 address (resolve names first)"
        )

    def _hand_back(self, items: list[tuple[bytes, Address | None]]) -> None:
        if not items:
            return
        self._c["blocked"] += 1
        if self._on_blocked is not None:
            self._on_blocked(list(items))

    # ------------------------------------------------------------------ errors and the rest

    def _report(self, exc: OSError, *, sending: bool) -> None:
        c = self._c
        if isinstance(exc, ConnectionRefusedError):
            c["port_unreachable"] += 1
        if sending:
            c["send_errors"] += 1
            if exc.errno == errno.EMSGSIZE:
                c["too_big"] += 1
            elif exc.errno in (errno.ENOBUFS, errno.ENOMEM):
                c["no_buffer"] += 1
        else:
            c["receive_errors"] += 1
        if self._on_error is not None:
            self._on_error(exc)

    def stats(self) -> dict[str, int]:
        return dict(self._c)

    def set_paused(self, paused: bool) -> None:
        self.paused = int(bool(paused))

    def set_on_batch(self, on_batch: BatchCallback) -> None:
        if not callable(on_batch):
            raise ArgumentTypeError("on_batch must be callable")
        self._on_batch = on_batch

    def close(self) -> None:
        self._closed = True
