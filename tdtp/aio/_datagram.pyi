"""Type stub of the compiled datagram engine (tdtp/aio/_datagram.c)."""

from collections.abc import Callable

from tdtp.session.events import Address

MAX_BATCH: int
MIN_BUFFER: int
MAX_BUFFER: int
MAX_TOTAL: int
MAX_SEGMENTS: int

class Engine:
    batch: int
    buffer_size: int
    rounds: int
    paused: int
    segmenting: int
    receive_coalescing: int
    def __init__(
        self,
        fd: int,
        family: int,
        batch: int,
        buffer_size: int,
        on_batch: Callable[[list[bytes], list[Address], list[int] | None, list[int] | None], None],
        *,
        on_error: Callable[[OSError], None] | None = None,
        on_blocked: Callable[[list[tuple[bytes, Address | None]]], None] | None = None,
        timestamps: bool = False,
        traffic_class: bool = False,
        coalesce: bool = False,
    ) -> None: ...
    def drain(self) -> int: ...
    def send(
        self, data: bytes | bytearray | memoryview, addr: Address | None = None, /
    ) -> bool: ...
    def send_batch(self, items: list[tuple[bytes, Address | None]], /) -> int: ...
    def stats(self) -> dict[str, int]: ...
    def set_paused(self, paused: bool, /) -> None: ...
    def close(self) -> None: ...
