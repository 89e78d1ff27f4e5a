"""Pre-shared keys: the secret a master and its slave were paired with, and a slave's ring of them.

A robot and its operator station are paired once, out of band, with a random 32-byte secret
(``tdtp keygen``). The master presents the key's public *identifier* in its OPEN; the slave looks the
identifier up in its :class:`KeyRing` (one key per master it may serve) and proves, like the master, that
it holds the same secret by deriving the same session keys (``derivation.py``).
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterable, Iterator, Mapping
from typing import Final

from tdtp.errors import InvalidKeyError
from tdtp.protection.derivation import derive_key_id, derive_reset_key

KEY_SIZE: Final = 32
"""Bytes of a generated key (256 bits)."""
MIN_KEY_SIZE: Final = 16
"""Shortest secret accepted: the keys must be random bytes, not a password (no stretching is done)."""
MAX_KEY_SIZE: Final = 64


class PresharedKey:
    """A secret shared by a master and a slave, with an optional human name for logs and stats.

    The secret never appears in ``repr`` or ``str``; :attr:`key_id` (8 bytes derived from the secret
    with HKDF) is what travels on the wire.
    """

    __slots__ = ("_secret", "key_id", "name", "reset_key")

    def __init__(self, secret: bytes, name: str = "") -> None:
        if not isinstance(secret, bytes | bytearray | memoryview):
            raise InvalidKeyError(f"a key's secret must be bytes, got {type(secret).__name__}")
        secret = bytes(secret)
        if not MIN_KEY_SIZE <= len(secret) <= MAX_KEY_SIZE:
            raise InvalidKeyError(
                f"a pre-shared key must be {MIN_KEY_SIZE}..{MAX_KEY_SIZE} random bytes "
                f"({KEY_SIZE} recommended: tdtp keygen), got {len(secret)}"
            )
        if not isinstance(name, str) or any(c.isspace() for c in name):
            raise InvalidKeyError(f"a key's name must be a string without spaces, got {name!r}")
        self._secret = secret
        self.name = name
        self.key_id = derive_key_id(secret)
        """The public identifier an OPEN carries (8 bytes)."""
        self.reset_key = derive_reset_key(secret)
        """The key a slave's RESET tag proves it holds (HKDF of the secret; never on the wire)."""

    @classmethod
    def generate(cls, name: str = "") -> PresharedKey:
        """A new random 32-byte key from the operating system's CSPRNG."""
        return cls(secrets.token_bytes(KEY_SIZE), name)

    @property
    def secret(self) -> bytes:
        """The secret bytes (never printed by ``repr`` or ``str``)."""
        return self._secret

    @property
    def label(self) -> str:
        """The name if it has one, else the identifier in hex."""
        return self.name or self.key_id.hex()

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PresharedKey):
            return NotImplemented
        return secrets.compare_digest(self._secret, other._secret) and self.name == other.name

    def __hash__(self) -> int:
        return hash(self.key_id)

    def __repr__(self) -> str:
        name = f"name={self.name!r}, " if self.name else ""
        return f"PresharedKey({name}key_id={self.key_id.hex()})"


KeyInput = PresharedKey | bytes | bytearray | memoryview
"""A key as the API accepts it: a :class:`PresharedKey` or its raw secret bytes."""

OneKeyInput = KeyInput | Iterable[KeyInput] | Mapping[str, bytes]
"""What a master's ``key=`` accepts: one key, or a collection that holds exactly one (what
:func:`~tdtp.load_keys` returns for a file of one key)."""


def as_key(value: OneKeyInput) -> PresharedKey:
    """The one key ``key=`` names. A collection must hold exactly one: a master presents one key,
    and the error for several says how to choose (:func:`~tdtp.load_key`)."""
    if isinstance(value, PresharedKey):
        return value
    if isinstance(value, bytes | bytearray | memoryview):
        return PresharedKey(bytes(value))
    if isinstance(value, str | os.PathLike):
        raise InvalidKeyError(
            f"key= takes a key, not the path of a key file: pass key=tdtp.load_key({str(value)!r})"
        )
    if isinstance(value, Mapping):
        keys = [PresharedKey(secret, name) for name, secret in value.items()]
    elif isinstance(value, Iterable):
        keys = [as_key(key) for key in value]
    else:
        raise InvalidKeyError(
            f"a key must be a tdtp.PresharedKey or its secret bytes, got {type(value).__name__} "
            "(read one from a key file with tdtp.load_key(path))"
        )
    if len(keys) == 1:
        return keys[0]
    if not keys:
        raise InvalidKeyError(
            "key= got an empty collection: pass one key, e.g. key=tdtp.load_key(path)"
        )
    names = ", ".join(key.label for key in keys)
    raise InvalidKeyError(
        f"key= takes the one key a master presents, got {len(keys)} ({names}): pass "
        "key=tdtp.load_key(path) for a key file's first key or tdtp.load_key(path, name=NAME) "
        "for a named one (a slave takes them all: listen(keys=tdtp.load_keys(path)))"
    )


class KeyRing:
    """The keys a slave accepts, looked up by identifier: one per master it may serve."""

    __slots__ = ("_by_id",)

    def __init__(self, keys: KeyInput | Iterable[KeyInput] | Mapping[str, bytes]) -> None:
        items: list[PresharedKey]
        if isinstance(keys, Mapping):
            items = [PresharedKey(secret, name) for name, secret in keys.items()]
        elif isinstance(keys, PresharedKey | bytes | bytearray | memoryview):
            items = [as_key(keys)]
        else:
            items = [as_key(key) for key in keys]
        if not items:
            raise InvalidKeyError("a key ring needs at least one key")
        by_id: dict[bytes, PresharedKey] = {}
        for key in items:
            if key.key_id in by_id:
                raise InvalidKeyError(
                    f"two keys share the identifier {key.key_id.hex()} "
                    f"({by_id[key.key_id].label} and {key.label}): the same secret twice?"
                )
            by_id[key.key_id] = key
        self._by_id = by_id

    def find(self, key_id: bytes) -> PresharedKey | None:
        """The key whose identifier is ``key_id``, or ``None``."""
        return self._by_id.get(key_id)

    def __iter__(self) -> Iterator[PresharedKey]:
        return iter(self._by_id.values())

    def __len__(self) -> int:
        return len(self._by_id)

    def __repr__(self) -> str:
        return f"KeyRing({', '.join(key.label for key in self)})"


KeysInput = KeyRing | KeyInput | Iterable[KeyInput] | Mapping[str, bytes]
"""What ``listen(keys=...)`` accepts: a ring, one key, several, or a name -> secret mapping."""


def as_key_ring(value: KeysInput) -> KeyRing:
    return value if isinstance(value, KeyRing) else KeyRing(value)
