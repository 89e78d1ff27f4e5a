"""Rate control: the controller interface, the paper's equations, and the controllers by name.

``teleop`` (the default) judges congestion by queueing delay together with loss and caps the flow at
a TCP's byte rate; ``trinomial`` is the paper's IPG controller (eqs. 9 and 10) capped by eq. 2; ``tfrc``
is RFC 5348 fed by the piggybacked acknowledgements; ``fixed`` is the constant-rate, UDP-like
baseline. docs/CONTROL.md describes the design and its defaults.
"""

from tdtp.control.base import NO_LIMIT, PacingSchedule, RateController
from tdtp.control.equations import padhye_rate, tcp_friendly_rate, tfrc_rate
from tdtp.control.fixed import FixedConfig, FixedRateController
from tdtp.control.registry import (
    DEFAULT_CONTROLLER,
    available_controllers,
    create_controller,
    register_controller,
)
from tdtp.control.teleop import TeleopConfig, TeleopController
from tdtp.control.tfrc import TfrcConfig, TfrcController
from tdtp.control.trinomial import (
    RECOVERY_RTTS,
    TrinomialConfig,
    TrinomialController,
    recovery_intervals,
)

__all__ = [
    "DEFAULT_CONTROLLER",
    "NO_LIMIT",
    "RECOVERY_RTTS",
    "FixedConfig",
    "FixedRateController",
    "PacingSchedule",
    "RateController",
    "TeleopConfig",
    "TeleopController",
    "TfrcConfig",
    "TfrcController",
    "TrinomialConfig",
    "TrinomialController",
    "available_controllers",
    "create_controller",
    "padhye_rate",
    "recovery_intervals",
    "register_controller",
    "tcp_friendly_rate",
    "tfrc_rate",
]
