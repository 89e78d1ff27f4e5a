"""What the operator and the robot of the 7-joint arm say to each other (shared by both scripts).

Two kinds of traffic share one keyed TDTP session:

* **samples**, 1000 times a second each way, typed with :class:`tdtp.teleop.schema.SampleCodec`:
  the operator's :class:`JointCommand` (the joint angles it wants) and the robot's :class:`JointState`
  (where the joints are, the mode, whether it is stopped or holding). A newer sample replaces an older
  one that has not left yet: only the newest matters.
* **control messages** on the session's reliable channel (``ep.send_control``), for what must arrive
  exactly once and in order: an emergency stop, a resume, a mode change. The robot answers each one
  it has applied with ``DONE <message>``.
"""

from __future__ import annotations

from dataclasses import dataclass

from tdtp.teleop.schema import SampleCodec

JOINTS = 7

ESTOP = b"ESTOP"
"""Stop now and ignore commands until RESUME."""
RESUME = b"RESUME"
MODES = ("position", "compliant")
"""``position``: the joints follow the command stiffly; ``compliant``: slowly, as if on springs."""


def mode_message(mode: str) -> bytes:
    """The control message that switches the robot to ``mode``."""
    return b"MODE " + mode.encode()


def done_message(message: bytes) -> bytes:
    """The robot's answer once it has applied ``message``."""
    return b"DONE " + message


@dataclass(frozen=True, slots=True)
class JointCommand:
    """Operator to robot: the joint angles wanted (radians) and the gripper's opening (0-255)."""

    sent_at: float
    q: tuple[float, ...]
    gripper: int


@dataclass(frozen=True, slots=True)
class JointState:
    """Robot to operator: where the joints are, the mode (an index into MODES) and two flags."""

    sent_at: float
    q: tuple[float, ...]
    mode: int
    stopped: bool
    """An emergency stop is in force."""
    holding: bool
    """The operator has gone silent (the watchdog): the joints hold where they are."""


COMMAND = SampleCodec(JointCommand, sent_at="f64", q=f"f32[{JOINTS}]", gripper="u8")
STATE = SampleCodec(
    JointState, sent_at="f64", q=f"f32[{JOINTS}]", mode="u8", stopped="bool", holding="bool"
)
