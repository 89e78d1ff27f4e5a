"""Capture files: UDP datagrams written as a classic pcap file that Wireshark and tshark open.

The classic libpcap format is small enough to write directly (no library of ours to keep up with,
nothing to install): a 24-byte file header, then per packet a 16-byte record header and the packet.
The link type is ``LINKTYPE_RAW`` (101): each packet starts with its IP header, version 4 or 6, so one
file holds both families. Each datagram gets a real IP header (IPv4: no options, DF, TTL 64, header
checksum; IPv6: hop limit 64) and a UDP header with its checksum, so the capture reads as if taken on
the wire (``tools/wireshark/tdtp.lua`` then decodes the TDTP inside).

Reference: the pcap file format (draft-ietf-opsawg-pcap; also the libpcap savefile man page) and
the link-layer type registry (LINKTYPE_RAW = 101).

A writer never raises once open: a failed write (disk full) stops the capture and is kept in
:attr:`PcapWriter.error`, because capturing must never take an endpoint down. The file grows by the
datagram plus 44 (IPv4) or 64 (IPv6) bytes per packet: about 0.35 MB/s for a 1 kHz, 100-byte session
seen from one end (both directions).
"""

from __future__ import annotations

import ipaddress
import os
import struct
import sys
import time
from typing import Any, BinaryIO, Final

from tdtp.errors import TdtpError

__all__ = ["LINKTYPE_RAW", "SNAPLEN", "CaptureError", "PcapWriter"]

LINKTYPE_RAW: Final = 101
"""Raw IP: the packet begins with the IPv4 or IPv6 header (the version nibble tells which)."""
SNAPLEN: Final = 65535
"""The largest datagram recorded whole (the pcap header's snapshot length)."""
_FILE_HEADER: Final = struct.Struct("<IHHiIII")  # magic, 2.4, thiszone, sigfigs, snaplen, network
_MAGIC_MICROSECONDS: Final = 0xA1B2C3D4
_RECORD: Final = struct.Struct("<IIII")  # seconds, microseconds, captured length, original length
_IPV4: Final = struct.Struct("!BBHHHBBH4s4s")
_IPV6: Final = struct.Struct("!IHBB16s16s")
_UDP: Final = struct.Struct("!HHHH")
_PROTO_UDP: Final = 17
_TTL: Final = 64
_MAX_ADDRESSES: Final = 1024
"""Parsed addresses cached (a server's peers); past this the cache starts again."""
_LITTLE_ENDIAN: Final = sys.byteorder == "little"

IpAddress = ipaddress.IPv4Address | ipaddress.IPv6Address


class CaptureError(TdtpError, OSError):
    """The capture file cannot be created or written; the message names it and the reason."""


def _checksum(data: bytes) -> int:
    """The Internet checksum (RFC 1071) of ``data``: ones' complement of the ones' complement sum of
    its 16-bit words. Summed in native byte order and swapped at the end (RFC 1071, 2(B))."""
    if len(data) % 2:
        data += b"\0"
    total = sum(memoryview(data).cast("H"))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    if _LITTLE_ENDIAN:
        total = ((total & 0xFF) << 8) | (total >> 8)
    return ~total & 0xFFFF


class PcapWriter:
    """Writes UDP datagrams into a new classic pcap file (``LINKTYPE_RAW``)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        try:
            self._file: BinaryIO | None = open(self.path, "wb")  # noqa: SIM115 -- closed in close()
            self._file.write(
                _FILE_HEADER.pack(_MAGIC_MICROSECONDS, 2, 4, 0, 0, SNAPLEN, LINKTYPE_RAW)
            )
        except OSError as exc:
            raise CaptureError(
                f"cannot write the capture file {self.path}: {exc.strerror or exc}; "
                "choose a path in a writable directory"
            ) from None
        self.packets = 0
        """Datagrams written."""
        self.error: str | None = None
        """Why writing stopped early (a failed write), or ``None``."""
        self._ident = 0
        self._addresses: dict[Any, IpAddress] = {}

    @property
    def closed(self) -> bool:
        """Whether the file is closed (by :meth:`close`, or after a write failed: :attr:`error`)."""
        return self._file is None

    def _address(self, host: Any) -> IpAddress:
        address = self._addresses.get(host)
        if address is None:
            text = str(host).split("%", 1)[0]  # an IPv6 scope (fe80::1%eth0) is not on the wire
            try:
                address = ipaddress.ip_address(text)
            except ValueError:
                address = ipaddress.IPv4Address(0)  # a name, not an address: unknown host
            if len(self._addresses) >= _MAX_ADDRESSES:
                self._addresses.clear()
            self._addresses[host] = address
        return address

    def write_udp(
        self,
        source: tuple[Any, ...],
        destination: tuple[Any, ...],
        payload: bytes,
        timestamp: float | None = None,
    ) -> None:
        """Record one UDP datagram from ``source`` to ``destination`` (socket addresses as asyncio
        gives them) at ``timestamp`` (seconds since the epoch; now if omitted)."""
        file = self._file
        if file is None:
            return
        src, dst = self._address(source[0]), self._address(destination[0])
        if src.version != dst.version:  # one family per packet: map IPv4 into IPv6
            src, dst = _as_ipv6(src), _as_ipv6(dst)
        sport, dport = int(source[1]), int(destination[1])
        udp_length = 8 + len(payload)
        if src.version == 4:
            pseudo = src.packed + dst.packed + struct.pack("!BBH", 0, _PROTO_UDP, udp_length)
        else:
            pseudo = src.packed + dst.packed + struct.pack("!I3xB", udp_length, _PROTO_UDP)
        udp = _UDP.pack(sport, dport, udp_length, 0)
        checksum = _checksum(pseudo + udp + payload) or 0xFFFF  # 0 means "none" in UDP
        udp = _UDP.pack(sport, dport, udp_length, checksum)
        if src.version == 4:
            self._ident = (self._ident + 1) & 0xFFFF
            total = 20 + udp_length
            header = _IPV4.pack(
                0x45, 0, total, self._ident, 0x4000, _TTL, _PROTO_UDP, 0, src.packed, dst.packed
            )
            header = header[:10] + _checksum(header).to_bytes(2, "big") + header[12:]
        else:
            header = _IPV6.pack(6 << 28, udp_length, _PROTO_UDP, _TTL, src.packed, dst.packed)
        packet = header + udp + payload
        length = len(packet)
        captured = min(length, SNAPLEN)
        if timestamp is None:
            timestamp = time.time()
        seconds = int(timestamp)
        micros = min(999_999, int((timestamp - seconds) * 1e6))
        try:
            file.write(_RECORD.pack(seconds, micros, captured, length) + packet[:captured])
        except (OSError, ValueError) as exc:  # ValueError: the file was closed under us
            self.error = f"writing {self.path} failed: {getattr(exc, 'strerror', None) or exc}"
            self._close_file()
            return
        self.packets += 1

    def flush(self) -> None:
        """Push what was written to the file (a failure closes it and is kept in :attr:`error`)."""
        if self._file is not None:
            try:
                self._file.flush()
            except (OSError, ValueError) as exc:
                self.error = f"writing {self.path} failed: {getattr(exc, 'strerror', None) or exc}"
                self._close_file()

    def close(self) -> None:
        """Flush and close the file. Idempotent."""
        self.flush()
        self._close_file()

    def _close_file(self) -> None:
        file, self._file = self._file, None
        if file is not None:
            try:
                file.close()
            except (OSError, ValueError) as exc:
                reason = getattr(exc, "strerror", None) or exc
                self.error = self.error or f"closing {self.path} failed: {reason}"

    def __enter__(self) -> PcapWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _as_ipv6(address: IpAddress) -> ipaddress.IPv6Address:
    if isinstance(address, ipaddress.IPv6Address):
        return address
    return ipaddress.IPv6Address(b"\0" * 10 + b"\xff\xff" + address.packed)
