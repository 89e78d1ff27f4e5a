"""Rate controllers by name: what ``ConnectionConfig(controller=..., controller_config=...)`` uses."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

from tdtp.control.base import RateController
from tdtp.control.fixed import FixedConfig, FixedRateController
from tdtp.control.teleop import TeleopConfig, TeleopController
from tdtp.control.tfrc import TfrcConfig, TfrcController
from tdtp.control.trinomial import TrinomialConfig, TrinomialController

__all__ = [
    "DEFAULT_CONTROLLER",
    "available_controllers",
    "controller_config_type",
    "create_controller",
    "judges_one_way_delay",
    "register_controller",
]

DEFAULT_CONTROLLER: Final[str] = "teleop"

_registry: dict[str, tuple[Callable[[Any], RateController], type[Any]]] = {}


def register_controller(
    name: str, controller_cls: Callable[[Any], RateController], config_cls: type[Any]
) -> None:
    """Make ``controller_cls(config)`` available as ``name``; ``config_cls()`` must give defaults.

    Registering the same pair under the same name again is a no-op; taking a name that is already
    used by another class raises :class:`ValueError`.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"a controller name must be a non-empty string, got {name!r}")
    if not (isinstance(controller_cls, type) and issubclass(controller_cls, RateController)):
        raise TypeError(f"controller_cls must be a RateController subclass, got {controller_cls!r}")
    if not isinstance(config_cls, type):
        raise TypeError(f"config_cls must be a class (its instances configure {name!r})")
    existing = _registry.get(name)
    if existing is not None and existing != (controller_cls, config_cls):
        raise ValueError(
            f"controller name {name!r} is already taken by {existing[0].__name__}; "
            "register yours under another name"
        )
    _registry[name] = (controller_cls, config_cls)


def available_controllers() -> tuple[str, ...]:
    """The registered names, sorted."""
    return tuple(sorted(_registry))


def controller_config_type(name: str) -> type[Any] | None:
    """The config class of the controller registered as ``name``, or ``None`` if there is none."""
    entry = _registry.get(name) if isinstance(name, str) else None
    return None if entry is None else entry[1]


def judges_one_way_delay(name: str) -> bool:
    """Whether the controller registered as ``name`` reads one-way delays (its class says so with
    ``judges_one_way_delay``): a master running it opens its sessions with timestamps."""
    entry = _registry.get(name) if isinstance(name, str) else None
    return entry is not None and bool(getattr(entry[0], "judges_one_way_delay", False))


def create_controller(name: str, config: object | None = None) -> RateController:
    """A new controller registered as ``name``, configured by ``config`` (``None``: defaults)."""
    entry = _registry.get(name) if isinstance(name, str) else None
    if entry is None:
        raise ValueError(
            f"unknown controller {name!r}; known controllers: {', '.join(available_controllers())}"
        )
    controller_cls, config_cls = entry
    if config is None:
        config = config_cls()
    elif not isinstance(config, config_cls):
        raise TypeError(
            f"controller {name!r} is configured by {config_cls.__name__}, got "
            f"{type(config).__name__}; pass tdtp.control.{config_cls.__name__}(...) or None for "
            "its defaults"
        )
    return controller_cls(config)


register_controller(FixedRateController.name, FixedRateController, FixedConfig)
register_controller(TeleopController.name, TeleopController, TeleopConfig)
register_controller(TfrcController.name, TfrcController, TfrcConfig)
register_controller(TrinomialController.name, TrinomialController, TrinomialConfig)
