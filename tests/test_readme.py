"""The README's Python blocks run as written: each is executed as a module, and the asyncio one's
slave and master are run against each other on loopback for a fraction of a second."""

from __future__ import annotations

import asyncio
import re
import socket
from pathlib import Path
from typing import Any

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), re.DOTALL)


def _module(source: str) -> dict[str, Any]:
    """Run a block as a module that is not ``__main__`` (its ``if __name__`` guard stays shut)."""
    namespace: dict[str, Any] = {"__name__": "readme_block"}
    exec(compile(source, str(README), "exec"), namespace)  # our own README
    return namespace


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
    return port


async def _until_bound(port: int, patience: float = 30.0) -> None:
    """Until something (the README's slave) holds ``port``: one loop step is not always enough for
    it to bind, and a master that dials first fails at once on the ICMP port unreachable."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + patience
    while loop.time() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                return  # in use: the slave is there
        await asyncio.sleep(0.005)
    raise AssertionError(f"nothing bound 127.0.0.1:{port} within {patience} s")


def test_there_are_python_blocks() -> None:
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize(
    "source", [b for b in BLOCKS if "async def" not in b], ids=lambda b: b.split("\n", 1)[0]
)
def test_plain_blocks_run(source: str, capsys: pytest.CaptureFixture[str]) -> None:
    _module(source)
    assert "100 samples, the last b'position 99'" in capsys.readouterr().out


def _asyncio_block() -> dict[str, Any]:
    (source,) = [b for b in BLOCKS if "async def slave" in b]
    return _module(source)


def test_the_asyncio_slave_serves_every_master_and_holds_when_each_goes_away() -> None:
    block = _asyncio_block()
    driven: list[bytes] = []
    holds: list[int] = []
    ended: list[object] = []
    block["drive_motors"] = lambda position, age: driven.append(position)
    block["hold_position"] = lambda: holds.append(len(driven))
    serve = block["serve"]

    async def serve_and_count(ep: Any) -> None:
        await serve(ep)
        ended.append(ep)

    block["serve"] = serve_and_count  # slave() looks serve up when a master connects
    port = _free_port()

    async def scenario() -> None:
        slave = asyncio.create_task(block["slave"]("127.0.0.1", port))
        await _until_bound(port)
        # Two masters at once: the TaskGroup serves both.
        await asyncio.gather(
            block["master"]("127.0.0.1", port, seconds=0.3),
            block["master"]("127.0.0.1", port, seconds=0.3),
        )
        async with asyncio.timeout(30):
            while len(ended) < 2:  # each master closed: its control loop holds and ends
                await asyncio.sleep(0.01)
        slave.cancel()
        with pytest.raises(asyncio.CancelledError):
            await slave

    asyncio.run(scenario())
    assert driven and all(p.count(b" ") == 1 for p in driven)  # the joystick's positions
    assert holds and holds[-1] == len(driven)


def test_the_asyncio_master_reports_the_slave_going_away() -> None:
    block = _asyncio_block()
    driven: list[bytes] = []
    said: list[str] = []
    block["drive_motors"] = lambda position, age: driven.append(position)
    block["print"] = lambda *args: said.append(" ".join(map(str, args)))
    port = _free_port()

    async def scenario() -> None:
        slave = asyncio.create_task(block["slave"]("127.0.0.1", port))
        await _until_bound(port)
        master = asyncio.create_task(block["master"]("127.0.0.1", port, seconds=60.0))
        async with asyncio.timeout(30):
            while not driven:  # the master is connected and streaming
                await asyncio.sleep(0.01)
            slave.cancel()  # the slave stops: its server closes every session with a CLOSE
            await master  # ...and the master notices at its next send

    asyncio.run(scenario())
    assert len(said) == 1
    assert said[0].startswith("slave gone: TDTP connection closed (peer_close)")
