"""The models of benchmarks/closed_loop.py on their own, in simulated time (no sockets, no clock).

The benchmark's plumbing (processes, transports, relays, report) has its smoke test in
tests/test_benchmarks_smoke.py. MuJoCo and numpy come with the ``loop`` extra (``make test`` installs
it); without them these tests are skipped.
"""

from __future__ import annotations

import asyncio
import importlib
import struct
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
np = pytest.importorskip("numpy")
workspace = importlib.import_module("teleop_loop.workspace")
operator_model = importlib.import_module("teleop_loop.operator_model")
passivity = importlib.import_module("teleop_loop.passivity")
transports = importlib.import_module("teleop_loop.transports")
tcp_link = importlib.import_module("teleop_loop.tcp_link")


@pytest.fixture(scope="module")
def arm_module():  # type: ignore[no-untyped-def]
    pytest.importorskip("mujoco")
    return importlib.import_module("teleop_loop.arm")


def test_arm_settles_on_a_command_in_free_space(arm_module) -> None:  # type: ignore[no-untyped-def]
    arm = arm_module.Arm()
    target = (0.40, 0.05)
    for _ in range(600):  # 0.6 s
        arm.tick(target)
    x, y = arm.tip()
    assert abs(x - target[0]) < 0.5e-3 and abs(y - target[1]) < 0.5e-3
    assert max(abs(v) for v in arm.tip_velocity()) < 1e-3
    assert arm.contact_force() == (0.0, 0.0)


def test_the_wall_pushes_back_and_stops_the_arm(arm_module) -> None:  # type: ignore[no-untyped-def]
    arm = arm_module.Arm()
    beyond = workspace.CONTACT_X + 0.02  # the command is 2 cm inside the wall
    for _ in range(800):
        arm.tick((beyond, 0.0))
    fx, fy = arm.contact_force()
    # Held at the wall, the controller's spring pulls with KP * 2 cm and the wall pushes it back.
    assert fx == pytest.approx(-arm_module.KP * (beyond - arm.tip()[0]), rel=0.05)
    assert fx < -10.0 and abs(fy) < 1e-6
    assert 0.0 < arm.penetration() < 1e-3  # stiff: under a millimetre
    for _ in range(400):  # and lets go when the command leaves the wall
        arm.tick((0.40, 0.0))
    assert arm.contact_force() == (0.0, 0.0)


def test_inverse_kinematics_puts_the_tip_where_asked(arm_module) -> None:  # type: ignore[no-untyped-def]
    arm = arm_module.Arm(start=(0.42, -0.07))
    assert arm.tip() == pytest.approx((0.42, -0.07), abs=1e-9)
    with pytest.raises(ValueError, match="reach"):
        arm_module.inverse_kinematics(0.7, 0.0)


def _operator_path(
    seed: int, feedback: tuple[float, float] = (0.0, 0.0)
) -> list[tuple[float, float]]:
    operator = operator_model.Operator(operator_model.ReferenceMotion(seed, 3.0))
    return [operator.step(i * workspace.TICK, feedback) for i in range(3000)]


def test_operator_is_repeatable_from_a_seed_and_differs_between_seeds() -> None:
    assert _operator_path(7) == _operator_path(7)
    assert _operator_path(7) != _operator_path(8)


def test_operator_reaches_past_the_wall_and_feels_the_force() -> None:
    reference = operator_model.ReferenceMotion(3, 6.0)
    xs = [reference.at(i * 0.001)[0][0] for i in range(6000)]
    assert xs[0] == operator_model.REST[0]
    assert max(xs) > workspace.CONTACT_X + 0.005  # it means to press into the wall
    free = max(x for x, _ in _operator_path(3))
    pushed = max(x for x, _ in _operator_path(3, feedback=(-15.0, 0.0)))
    assert pushed < free - 0.01  # a force against the hand moves the device back
    operator = operator_model.Operator(reference)
    operator.step(0.0, (-100.0, 0.0))
    assert operator.rendered == (-operator_model.MAX_RENDERED_FORCE, 0.0)  # the motors saturate


def test_passivity_observer_sign() -> None:
    t = np.arange(0.0, 2.0, 0.001)
    v = np.cos(2 * np.pi * t)[:, None]
    zero = np.zeros_like(v)
    # A damper at the master port takes energy in: passive, E grows.
    passive = passivity.summarise(passivity.observe(0.001, -5.0 * v, v, zero, zero))
    assert passive.injected_j == 0.0 and passive.final_j > 0.0 and passive.active_fraction == 0.0
    # A negative damper pushes the hand along: the channel generates energy, E falls below zero.
    active = passivity.summarise(passivity.observe(0.001, 5.0 * v, v, zero, zero))
    assert active.injected_j == pytest.approx(5.0 * 1.0, rel=0.01)  # 5 * mean(cos^2) * 2 s
    assert active.final_j < 0.0 and active.active_fraction > 0.99
    # An ideal channel (the slave port gets what the master port gave) is lossless.
    x = np.sin(2 * np.pi * t)[:, None] / (2 * np.pi)
    ideal = passivity.observe(0.001, -100.0 * x, v, -100.0 * x, v)
    assert np.max(np.abs(ideal)) < 1e-9


def test_newest_sample_ignores_a_late_older_one() -> None:
    newest = transports.NewestSample()

    def sample(index: int) -> bytes:
        return struct.pack(">dI", 0.0, index) + bytes(88)

    newest.offer(sample(5))
    newest.offer(sample(4))  # reordered behind 5
    assert newest.payload == sample(5)
    newest.offer(sample(0xFFFFFFFF))  # far behind, not ahead
    assert newest.payload == sample(5)
    newest.offer(b"short")
    assert newest.payload == sample(5) and newest.received == 4


def test_tcp_path_delivers_in_order_through_loss() -> None:
    """The TCP emulation loses segments on the link and still delivers every byte, in order."""

    async def run() -> tuple[bytes, dict[str, int]]:
        to_slave, _ = tcp_link.paths("delay 2ms loss 20%", seed=5)
        reader = asyncio.StreamReader()
        out = bytearray()

        class Sink:
            def write(self, data: bytes) -> None:
                out.extend(data)

        task = asyncio.get_running_loop().create_task(to_slave.run(reader, Sink()))
        data = bytes(range(256)) * 40
        for i in range(0, len(data), 100):
            reader.feed_data(data[i : i + 100])
            await asyncio.sleep(0)
        for _ in range(3000):  # wait for the retransmissions (RTO doubling from 200 ms)
            if len(out) == len(data):
                break
            await asyncio.sleep(0.01)
        reader.feed_eof()
        await task
        stats = to_slave.stats
        return bytes(out), {
            "retransmissions": stats.retransmissions,
            "lost": to_slave.link.stats.lost,
        }

    received, counts = asyncio.run(run())
    assert received == bytes(range(256)) * 40
    assert counts["lost"] > 0 and counts["retransmissions"] >= counts["lost"]


def test_newest_sample_takes_the_run_over_the_warm_up() -> None:
    """Warm-up samples are numbered just below the run's first, modulo 2**32."""
    sides = importlib.import_module("teleop_loop.sides")
    newest = transports.NewestSample()

    def sample(index: int) -> bytes:
        return struct.pack(">dI", 0.0, index) + bytes(88)

    newest.offer(sample(sides.WARMUP_INDEX + 7))
    newest.offer(sample(0))
    assert newest.payload == sample(0)
    newest.offer(sample(sides.WARMUP_INDEX + 8))  # a late warm-up sample
    assert newest.payload == sample(0)


class _Wire:
    """An in-memory channel: what one end sends, the other reads as its newest sample."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send(self, payload: bytes) -> None:
        self.sent.append(payload)

    def latest(self) -> bytes | None:
        return self.sent[-1] if self.sent else None

    def packets_sent(self) -> int | None:
        return len(self.sent)

    def details(self) -> dict[str, int]:
        return {}

    async def close(self) -> None:
        pass


def test_deadband_sends_velocity_changes_and_the_slave_extrapolates(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    deadband_channel = importlib.import_module("teleop_loop.deadband_channel")
    haptic = importlib.import_module("tdtp.teleop.haptic_sample")
    wire = _Wire()
    master = deadband_channel.DeadbandChannel(wire, sends="command")  # type: ignore[arg-type]
    slave = deadband_channel.DeadbandChannel(wire, sends="force")  # type: ignore[arg-type]
    clock = [0.0]
    monkeypatch.setattr(deadband_channel.tdtp, "monotonic", lambda: clock[0])
    v = 0.1  # m/s along x, 50 ticks
    for tick in range(50):
        clock[0] = tick * workspace.TICK
        position = (0.35 + v * tick * workspace.TICK, 0.0, 0.0)
        master.send(haptic.HapticSample(clock[0], tick, position, (0.0, 0.0, 0.0)).encode(100))
        slave.latest()
    # At rest, then moving: two samples; a constant velocity sends nothing more within max_hold.
    assert len(wire.sent) == 2 and master.sender.stats.offered == 50
    # The slave reads the command extrapolated along the slope of the two it received.
    clock[0] = 0.049
    command = haptic.HapticSample.decode(slave.latest())
    assert command.position[0] == pytest.approx(0.35 + v * 0.049, abs=1e-6)
    # The master holds the force it received; a 10 % change of it is not sent.
    slave.send(haptic.HapticSample(0.05, 50, (0.45, 0.0, 0.0), (-10.0, 0.0, 0.0)).encode(100))
    slave.send(haptic.HapticSample(0.051, 51, (0.45, 0.0, 0.0), (-10.5, 0.0, 0.0)).encode(100))
    assert len(wire.sent) == 3
    force = haptic.HapticSample.decode(master.latest()).force
    assert force[0] == pytest.approx(-10.0)
