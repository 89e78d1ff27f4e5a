"""What every scenario returns: a result with ``to_dict()``/``to_json()``, JSON-safe (no NaN)."""

from __future__ import annotations

import json
import math
from typing import Any, ClassVar


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def json_safe(data: Any) -> Any:
    """Make a structure JSON-safe: NaN and infinities become ``None``."""
    if isinstance(data, float):
        return _finite(data)
    if isinstance(data, dict):
        return {k: json_safe(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_safe(v) for v in data]
    return data


class ScenarioResult:
    """A scenario's result. As plain data (:meth:`to_dict`) every one leads with the same three keys:
    ``scenario`` (its name), ``params`` (what it ran with) and ``headline``; then its own
    :meth:`details`."""

    scenario: ClassVar[str]
    params: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """The result as plain data: name, parameters, headline, then :meth:`details`."""
        return {
            "scenario": self.scenario,
            "params": self.params,
            "headline": self.headline(),
            **self.details(),
        }

    def details(self) -> dict[str, Any]:
        """What follows the headline in :meth:`to_dict`: the runs, per-seed records and the like."""
        raise NotImplementedError

    def to_json(self, *, indent: int | None = None) -> str:
        """The whole result as JSON (NaN and infinities as ``null``)."""
        return json.dumps(json_safe(self.to_dict()), indent=indent, allow_nan=False)

    def headline(self) -> dict[str, Any]:
        raise NotImplementedError


def ratio(a: float, b: float) -> float:
    """``a / b``, NaN where either is not finite or ``b`` is zero (JSON: ``null``)."""
    return a / b if b and math.isfinite(a) and math.isfinite(b) else math.nan
