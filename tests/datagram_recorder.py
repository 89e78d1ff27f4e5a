"""What a datagram layer's ``on_receive`` was handed: the tests of tdtp.aio.datagram share it."""

from __future__ import annotations

from tdtp.session.events import Address


class Recorder:
    """One entry per callback, and the errors reported to ``on_error``."""

    def __init__(self) -> None:
        self.batches: list[
            tuple[list[bytes], list[Address], list[int] | None, list[int] | None]
        ] = []
        self.errors: list[OSError] = []

    def __call__(
        self,
        datas: list[bytes],
        addrs: list[Address],
        stamps: list[int] | None,
        classes: list[int] | None,
    ) -> None:
        assert len(addrs) == len(datas)
        assert stamps is None or len(stamps) == len(datas)
        assert classes is None or len(classes) == len(datas)
        self.batches.append((datas, addrs, stamps, classes))

    @property
    def datagrams(self) -> list[bytes]:
        return [d for batch in self.batches for d in batch[0]]

    @property
    def sources(self) -> list[Address]:
        return [a for batch in self.batches for a in batch[1]]
