"""A batched UDP datagram layer for the asyncio loop: ``recvmmsg`` / ``sendmmsg`` in compiled code.

Python's ``socket`` has neither ``recvmmsg`` nor ``sendmmsg``, and neither asyncio's nor uvloop's
datagram transport batches: every datagram is one system call and one Python call each way. Here one
non-blocking UDP socket is registered with the running loop's reader (``loop.add_reader``, on uvloop
and asyncio alike), and each time it is readable the compiled engine (``tdtp/aio/_datagram.c``)
drains it with ``recvmmsg`` into buffers allocated once, handing every batch to ``on_receive`` in one
call::

    on_receive(datagrams, addresses, timestamps_ns, traffic_class)

``timestamps_ns`` (the kernel's receive time, ``SO_TIMESTAMPNS``, CLOCK_REALTIME in ns) and
``traffic_class`` (the IPv4 TOS / IPv6 traffic class byte; ``& 3`` is the ECN field) are lists
parallel to the datagrams when asked for (``timestamps=True``, ``ecn=True``), else ``None``; -1 where
the kernel gave none. :meth:`DatagramLayer.send_batch` sends a list of ``(data, addr)`` with one
``sendmmsg`` per ``batch``; :meth:`DatagramLayer.sendto` is one ``sendto``.

Coalescing (``coalesce=True``, the default; compiled engine, Linux). In ``send_batch`` a run of
datagrams to one destination with one length (the last may be shorter) leaves as one message with
``UDP_SEGMENT``: the kernel carries it through its stack once and cuts it into ordinary datagrams at
the end, so a burst costs one pass through the stack instead of one per datagram (the sender's
kernel time per datagram falls several times over on loopback). The socket also asks for
``UDP_GRO``: the kernel may hand a run from one source over as one buffer, which the engine cuts back
into datagrams, so ``on_receive`` sees exactly the datagrams that were sent. A route or kernel that
refuses segmentation turns it off for the layer and the refused run is sent again one by one
(``segmentation_refused``); ``coalesced_sends``, ``coalesced_received``, ``segmenting`` and
``receive_coalescing`` in :attr:`DatagramLayer.stats` say what happened. Receive coalescing makes every
receive slot 64 KiB (``batch`` x 64 KiB of address space, allocated once; pages are only touched as
far as data arrives) and is left off where that exceeds the 16 MiB bound. The pure engine sends and
receives one datagram at a time.

Errors. Nothing a peer or the network does raises: every kernel error is counted
(:attr:`DatagramLayer.stats`) and, like asyncio's ``error_received``, reported to ``on_error``:
ECONNREFUSED (an ICMP port unreachable, on a connected socket) as :class:`ConnectionRefusedError`
(``port_unreachable``), EMSGSIZE (``too_big``) and ENOBUFS (``no_buffer``) as lost datagrams, EINTR
retried, EAGAIN on receive the end of a drain. A full send buffer (EAGAIN on send) holds the unsent
datagrams in a bounded queue (``max_pending``; beyond it they are dropped and counted), calls
``on_pause`` and waits for the socket to be writable, then sends them and calls ``on_resume``:
the same contract as a transport's ``pause_writing`` / ``resume_writing``. Datagrams longer than
``buffer_size`` are dropped and counted (``truncated``). Misuse raises a :class:`~tdtp.TdtpError`:
bad parameters, a non-numeric host, sending on a closed layer.

Engines. The compiled engine runs where setup.py could build it; the pure-Python one
(:mod:`tdtp.aio.datagram_pure`, same interface over ``recvfrom``/``recvmsg``/``sendto``) where it
could not, with ``TDTP_PURE_PYTHON=1``, or with ``engine="pure"``. :func:`datagram_build_info` says
which one a process gets by default.

``tdtp.connect`` and ``tdtp.listen`` run on this layer wherever the compiled engine is built
(:mod:`tdtp.aio.datagram_transport`; ``TDTP_DATAGRAM_LAYER=0`` selects the loop's own transport).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Final, Literal, Protocol

from tdtp._extensions import load_extension
from tdtp.errors import (
    AddressError,
    ArgumentTypeError,
    DatagramEngineUnavailableError,
    InvalidArgumentError,
)
from tdtp.session.events import Address

__all__ = [
    "DEFAULT_BATCH",
    "DEFAULT_BUFFER_SIZE",
    "BatchCallback",
    "DatagramLayer",
    "DatagramLayerInfo",
    "EngineChoice",
    "datagram_build_info",
    "open_datagram_endpoint",
]

BatchCallback = Callable[[list[bytes], list[Address], list[int] | None, list[int] | None], None]
"""``on_receive(datagrams, addresses, timestamps_ns or None, traffic_class or None)``."""
EngineChoice = Literal["auto", "compiled", "pure"]
DEFAULT_BATCH: Final = 64
DEFAULT_BUFFER_SIZE: Final = 2048
"""Bytes per receive buffer: a TDTP datagram is at most a few hundred bytes; longer ones are
dropped and counted (``truncated``)."""
_SOURCE: Final = Path(__file__).with_name("_datagram.c")


class _Engine(Protocol):
    batch: int
    buffer_size: int
    rounds: int
    paused: int

    def drain(self) -> int: ...
    def send(self, data: bytes, addr: Address | None = None, /) -> bool: ...
    def send_batch(self, items: list[tuple[bytes, Address | None]], /) -> int: ...
    def stats(self) -> dict[str, int]: ...
    def set_paused(self, paused: bool, /) -> None: ...
    def set_on_batch(self, on_batch: BatchCallback, /) -> None: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class DatagramLayerInfo:
    """Which datagram engine :func:`open_datagram_endpoint` uses by default: ``"compiled"`` (C,
    recvmmsg/sendmmsg) or ``"pure"``, and why the pure one (``""`` for the compiled one)."""

    engine: str
    reason: str

    @property
    def compiled(self) -> bool:
        return self.engine == "compiled"

    def describe(self) -> str:
        """One phrase for a banner."""
        if self.compiled:
            return "compiled (C, recvmmsg/sendmmsg)"
        return f"pure Python ({self.reason})"


def _load_compiled() -> tuple[ModuleType | None, str]:
    return load_extension("tdtp.aio._datagram", _SOURCE)


_COMPILED, _REASON = _load_compiled()


def datagram_build_info() -> DatagramLayerInfo:
    """Which datagram engine this process uses by default, and why."""
    if _COMPILED is not None:
        return DatagramLayerInfo("compiled", "")
    return DatagramLayerInfo("pure", _REASON)


def _check_flag(name: str, value: object) -> bool:
    if not isinstance(value, bool):
        raise ArgumentTypeError(f"{name} must be True or False, got {value!r}")
    return value


class DatagramLayer:
    """One UDP socket on the running loop, received and sent in batches. Create it with
    :func:`open_datagram_endpoint`; see the module's documentation for the callbacks and errors.

    ``sendto`` and ``send_batch`` are the engine's own methods (no Python call in between)."""

    sendto: Callable[..., bool]
    """``sendto(data, addr=None) -> bool``: one system call; False when the datagram was lost
    (counted, reported to ``on_error``) or held because the send buffer is full."""
    send_batch: Callable[[list[tuple[bytes, Address | None]]], int]
    """``send_batch([(data, addr or None), ...]) -> int``: one ``sendmmsg`` per ``batch``
    datagrams (the pure engine: one ``sendto`` each); returns how many the kernel took."""

    def __init__(
        self,
        sock: socket.socket,
        loop: asyncio.AbstractEventLoop,
        on_receive: BatchCallback,
        *,
        on_error: Callable[[OSError], None] | None,
        on_pause: Callable[[], None] | None,
        on_resume: Callable[[], None] | None,
        batch: int,
        buffer_size: int,
        timestamps: bool,
        ecn: bool,
        coalesce: bool,
        engine: EngineChoice,
        max_pending: int,
    ) -> None:
        self._sock = sock
        self._loop = loop
        self._fd = sock.fileno()
        self._on_pause = on_pause
        self._on_resume = on_resume
        self._pending: deque[tuple[bytes, Address | None]] = deque()
        self._max_pending = max_pending
        self.pending_dropped = 0
        """Datagrams dropped because the send buffer was full and ``max_pending`` were held."""
        self.rearmed = 0
        """Times the socket was registered with the loop again after a kernel error."""
        self._closed = False
        self._writing = False
        self._on_error = on_error
        self._rearm_due = False
        family = int(sock.family)
        module = _COMPILED if engine in ("auto", "compiled") else None
        impl: _Engine
        if module is not None:
            impl = module.Engine(
                self._fd,
                family,
                batch,
                buffer_size,
                on_receive,
                on_error=self._error,
                on_blocked=self._blocked,
                timestamps=timestamps,
                traffic_class=ecn,
                coalesce=coalesce,
            )
            self.engine = "compiled"
        else:
            from tdtp.aio.datagram_pure import PureEngine  # noqa: PLC0415 - only when needed

            impl = PureEngine(
                sock,
                family,
                batch,
                buffer_size,
                on_receive,
                on_error=self._error,
                on_blocked=self._blocked,
                timestamps=timestamps,
                traffic_class=ecn,
            )
            self.engine = "pure"
        self._impl = impl
        self.sendto = impl.send
        self.send_batch = impl.send_batch
        loop.add_reader(self._fd, impl.drain)

    # ------------------------------------------------------------------ introspection

    @property
    def socket(self) -> socket.socket:
        """The underlying socket (for options; do not read from it or close it yourself)."""
        return self._sock

    @property
    def sockname(self) -> Address:
        name: Address = self._sock.getsockname()
        return name

    @property
    def batch(self) -> int:
        return self._impl.batch

    @property
    def buffer_size(self) -> int:
        return self._impl.buffer_size

    @property
    def write_paused(self) -> bool:
        """True while the send buffer is full and sends are held (at most ``max_pending``)."""
        return self._writing

    @property
    def pending(self) -> int:
        return len(self._pending)

    @property
    def stats(self) -> dict[str, int]:
        """The engine's counters (received, batches, system calls, errors by kind, ...) and
        ``pending_dropped``."""
        stats = self._impl.stats()
        stats["pending_dropped"] = self.pending_dropped
        return stats

    @property
    def is_closed(self) -> bool:
        return self._closed

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<DatagramLayer {self.engine} batch={self.batch} {state}>"

    def set_receiver(self, on_receive: BatchCallback) -> None:
        """Hand the next batches to ``on_receive`` instead (called by the engine directly, no
        Python call in between)."""
        self._impl.set_on_batch(on_receive)

    # ------------------------------------------------------------------ errors

    def _error(self, exc: OSError) -> None:
        """A kernel error the engine counted: re-register the socket with the loop soon, then tell
        the application. uvloop (libuv's uv_poll) stops watching a descriptor for good once epoll
        reports EPOLLERR on it, which an ICMP error on a connected socket does, after one last call
        of the reader; asyncio's selector loop does not, and re-registering costs it nothing."""
        if not self._rearm_due and not self._closed:
            self._rearm_due = True
            self._loop.call_soon(self._rearm)
        if self._on_error is not None:
            self._on_error(exc)

    def _rearm(self) -> None:
        self._rearm_due = False
        if self._closed or self._loop.is_closed():
            return
        loop, fd = self._loop, self._fd
        loop.remove_reader(fd)
        loop.add_reader(fd, self._impl.drain)
        if self._writing:
            loop.remove_writer(fd)
            loop.add_writer(fd, self._writable)
        self.rearmed += 1

    # ------------------------------------------------------------------ flow control

    def _blocked(self, items: list[tuple[bytes, Address | None]]) -> None:
        pending = self._pending
        room = self._max_pending - len(pending)
        if room < len(items):
            self.pending_dropped += len(items) - max(room, 0)
            items = items[: max(room, 0)]
        pending.extend(items)
        if not self._writing and not self._closed:
            self._writing = True
            self._impl.set_paused(True)
            self._loop.add_writer(self._fd, self._writable)
            if self._on_pause is not None:
                self._on_pause()

    def _writable(self) -> None:
        impl = self._impl
        impl.set_paused(False)
        pending = self._pending
        items = list(pending)
        pending.clear()
        self._writing = False  # a send that blocks again re-enters _blocked and pauses anew
        if items:
            impl.send_batch(items)
        if not self._writing:
            self._loop.remove_writer(self._fd)
            if self._on_resume is not None:
                self._on_resume()

    # ------------------------------------------------------------------ ending

    def close(self) -> None:
        """Unregister from the loop and close the socket; held datagrams are dropped. Idempotent."""
        if self._closed:
            return
        self._closed = True
        loop = self._loop
        if not loop.is_closed():
            loop.remove_reader(self._fd)
            if self._writing:
                loop.remove_writer(self._fd)
        self._writing = False
        self._pending.clear()
        self._impl.close()
        self._sock.close()

    async def __aenter__(self) -> DatagramLayer:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        self.close()


def _choose_engine(engine: object) -> EngineChoice:
    if engine == "auto":
        return "auto"
    if engine == "pure":
        return "pure"
    if engine == "compiled":
        if _COMPILED is None:
            raise DatagramEngineUnavailableError(
                f"the compiled datagram engine cannot run here: {_REASON}"
            )
        return "compiled"
    raise InvalidArgumentError(f"engine must be 'auto', 'compiled' or 'pure', got {engine!r}")


async def _resolve(
    loop: asyncio.AbstractEventLoop, addr: tuple[str, int], family: int, action: str
) -> tuple[int, Address]:
    host, port = addr
    try:
        infos = await loop.getaddrinfo(host, port, family=family, type=socket.SOCK_DGRAM)
    except OSError as exc:
        raise _address_error(exc, action, host, port) from exc
    af, _, _, _, sockaddr = infos[0]
    return int(af), sockaddr


def _address_error(exc: OSError, action: str, host: object, port: int) -> AddressError:
    """The :class:`~tdtp.AddressError` for resolving, binding or connecting ``host:port``."""
    where = f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"
    if isinstance(exc, socket.gaierror):
        return AddressError(f"cannot {action} {where}: host name not resolved ({exc.strerror})")
    if exc.errno == errno.EADDRINUSE:
        return AddressError(f"cannot {action} {where}: the port is in use")
    if exc.errno == errno.EADDRNOTAVAIL:
        return AddressError(f"cannot {action} {where}: not an address of this host")
    return AddressError(f"cannot {action} {where}: {exc.strerror or exc}")


def _check_addr(name: str, addr: object) -> tuple[str, int] | None:
    if addr is None:
        return None
    if (
        not isinstance(addr, tuple)
        or len(addr) != 2
        or not isinstance(addr[0], str)
        or isinstance(addr[1], bool)
        or not isinstance(addr[1], int)
    ):
        raise ArgumentTypeError(f"{name} must be a (host, port) tuple or None, got {addr!r}")
    if not 0 <= addr[1] <= 65535:
        raise InvalidArgumentError(f"{name}'s port must be in 0..65535, got {addr[1]}")
    return addr


async def open_datagram_endpoint(
    on_receive: BatchCallback,
    *,
    local_addr: tuple[str, int] | None = None,
    remote_addr: tuple[str, int] | None = None,
    on_error: Callable[[OSError], None] | None = None,
    on_pause: Callable[[], None] | None = None,
    on_resume: Callable[[], None] | None = None,
    batch: int = DEFAULT_BATCH,
    buffer_size: int = DEFAULT_BUFFER_SIZE,
    timestamps: bool = False,
    ecn: bool = False,
    coalesce: bool = True,
    reuse_port: bool = False,
    engine: EngineChoice = "auto",
    max_pending: int | None = None,
) -> DatagramLayer:
    """Bind (``local_addr``) and/or connect (``remote_addr``) a non-blocking UDP socket and register
    it with the running loop. At least one address is needed; with ``remote_addr`` alone the socket
    binds to an ephemeral port of the remote's family. A connected socket receives only from its
    peer, and reports ICMP port unreachable as ``ConnectionRefusedError`` to ``on_error``.

    ``batch`` (1..1024) datagrams per system call and ``buffer_size`` (64..65536) bytes per receive
    buffer, ``batch x buffer_size`` at most 16 MiB, allocated once. ``max_pending`` (default
    ``batch``) bounds the datagrams held while the send buffer is full. ``engine``: ``"auto"`` (the
    compiled one where it runs), ``"compiled"`` (:class:`~tdtp.DatagramEngineUnavailableError` where
    it does not) or ``"pure"``.

    Raises :class:`~tdtp.InvalidArgumentError` / :class:`~tdtp.ArgumentTypeError` for bad arguments
    (before anything is bound) and :class:`~tdtp.AddressError` when an address cannot be resolved,
    bound or connected.
    """
    if not callable(on_receive):
        raise ArgumentTypeError(f"on_receive must be callable, got {on_receive!r}")
    for name, cb in (("on_error", on_error), ("on_pause", on_pause), ("on_resume", on_resume)):
        if cb is not None and not callable(cb):
            raise ArgumentTypeError(f"{name} must be callable or None, got {cb!r}")
    local = _check_addr("local_addr", local_addr)
    remote = _check_addr("remote_addr", remote_addr)
    if local is None and remote is None:
        raise InvalidArgumentError("give local_addr, remote_addr or both")
    timestamps = _check_flag("timestamps", timestamps)
    ecn = _check_flag("ecn", ecn)
    coalesce = _check_flag("coalesce", coalesce)
    reuse_port = _check_flag("reuse_port", reuse_port)
    if reuse_port and not hasattr(socket, "SO_REUSEPORT"):
        raise InvalidArgumentError("reuse_port=True needs SO_REUSEPORT, which this system lacks")
    from tdtp.aio.datagram_pure import check_parameters  # noqa: PLC0415

    check_parameters(socket.AF_INET, batch, buffer_size)
    if max_pending is None:
        max_pending = batch
    if isinstance(max_pending, bool) or not isinstance(max_pending, int) or max_pending < 0:
        raise InvalidArgumentError(f"max_pending must be an integer >= 0, got {max_pending!r}")
    choice = _choose_engine(engine)

    loop = asyncio.get_running_loop()
    family = 0
    remote_sockaddr: Address | None = None
    local_sockaddr: Address | None = None
    if remote is not None:
        family, remote_sockaddr = await _resolve(loop, remote, 0, "connect to")
    if local is not None:
        family, local_sockaddr = await _resolve(loop, local, family, "bind to")
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.setblocking(False)
        if reuse_port:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        if timestamps:
            sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_TIMESTAMPNS", 35), 1)
        if ecn:
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, getattr(socket, "IPV6_RECVTCLASS", 66), 1)
            # IPv4 (and IPv4-mapped peers of an IPv6 socket, where Linux allows it)
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_IP, getattr(socket, "IP_RECVTOS", 13), 1)
        where = local_sockaddr
        try:
            if local_sockaddr is not None:
                sock.bind(local_sockaddr)
            where = remote_sockaddr
            if remote_sockaddr is not None:
                sock.connect(remote_sockaddr)
        except OSError as exc:
            assert where is not None
            action = "bind to" if where is local_sockaddr else "connect to"
            raise _address_error(exc, action, where[0], int(where[1])) from exc
        return DatagramLayer(
            sock,
            loop,
            on_receive,
            on_error=on_error,
            on_pause=on_pause,
            on_resume=on_resume,
            batch=batch,
            buffer_size=buffer_size,
            timestamps=timestamps,
            ecn=ecn,
            coalesce=coalesce,
            engine=choice,
            max_pending=max_pending,
        )
    except BaseException:
        sock.close()
        raise
