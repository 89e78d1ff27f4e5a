"""Controllers by name: defaults, configs, and the errors a caller gets for a wrong name or config."""

from __future__ import annotations

from typing import Any

import pytest

from tdtp.control import (
    DEFAULT_CONTROLLER,
    FixedConfig,
    FixedRateController,
    TeleopController,
    TfrcConfig,
    TfrcController,
    TrinomialConfig,
    TrinomialController,
    available_controllers,
    create_controller,
    register_controller,
    registry,
)


def test_the_four_built_in_controllers() -> None:
    assert available_controllers() == ("fixed", "teleop", "tfrc", "trinomial")
    assert DEFAULT_CONTROLLER == "teleop"
    assert isinstance(create_controller("teleop"), TeleopController)
    assert isinstance(create_controller("fixed"), FixedRateController)
    assert isinstance(create_controller("tfrc"), TfrcController)
    assert isinstance(create_controller("trinomial"), TrinomialController)


def test_none_means_the_default_config() -> None:
    controller = create_controller("trinomial", None)
    assert isinstance(controller, TrinomialController)
    assert controller.config == TrinomialConfig()


def test_a_config_is_passed_through() -> None:
    fixed = create_controller("fixed", FixedConfig(rate=250.0))
    assert fixed.rate == 250.0
    tfrc = create_controller("tfrc", TfrcConfig(initial_rate=8.0))
    assert tfrc.rate == 8.0
    trinomial = create_controller("trinomial", TrinomialConfig(initial_rate=300.0))
    assert trinomial.rate == 300.0


def test_unknown_name_lists_the_known_ones() -> None:
    with pytest.raises(ValueError) as info:
        create_controller("foo")
    assert (
        str(info.value)
        == "unknown controller 'foo'; known controllers: fixed, teleop, tfrc, trinomial"
    )


def test_wrong_config_type_names_the_expected_class() -> None:
    with pytest.raises(TypeError, match="configured by TrinomialConfig, got TfrcConfig"):
        create_controller("trinomial", TfrcConfig())
    with pytest.raises(TypeError, match="FixedConfig"):
        create_controller("fixed", {"rate": 10.0})


def test_registering_a_new_controller(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(registry, "_registry", dict(registry._registry))

    class Slow(FixedRateController):
        name = "slow"

    register_controller("slow", Slow, FixedConfig)
    register_controller("slow", Slow, FixedConfig)  # the same pair again: a no-op
    assert available_controllers() == ("fixed", "slow", "teleop", "tfrc", "trinomial")
    assert isinstance(create_controller("slow", FixedConfig(rate=1.0)), Slow)
    with pytest.raises(ValueError, match="already taken by Slow"):
        register_controller("slow", FixedRateController, FixedConfig)


@pytest.mark.parametrize(
    ("name", "cls", "config", "error"),
    [
        ("", FixedRateController, FixedConfig, ValueError),
        ("x", object, FixedConfig, TypeError),
        ("x", FixedRateController, FixedConfig(), TypeError),
    ],
)
def test_bad_registrations(name: str, cls: Any, config: Any, error: type[Exception]) -> None:
    with pytest.raises(error):
        register_controller(name, cls, config)
