from collections.abc import Sequence
from typing import Any

class SlotFiller:
    """Builds an instance of a ``__slots__`` class from one value per slot name, stored straight
    into its slots (no ``__init__``)."""

    def __init__(self, cls: type, names: Sequence[str]) -> None: ...
    def __call__(self, *values: object) -> Any: ...
