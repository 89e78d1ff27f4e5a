"""Key files: how an operator stores the keys a master and its slave were paired with.

One key per line, ``NAME HEX`` or just ``HEX`` (64 hex digits for a 32-byte key); blank lines and
lines starting with ``#`` are ignored. A master's file normally holds its own key; a slave's holds one
line per master it may serve, the name saying which master it is. ``tdtp keygen`` writes one. The file
is the secret: it is created readable by its owner only, and a file others may read is refused.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from tdtp.errors import InvalidKeyError
from tdtp.protection.keys import PresharedKey


def parse_keys(text: str, source: str = "key file") -> list[PresharedKey]:
    """The keys in ``text`` (the key file format); raises :class:`InvalidKeyError` naming the line."""
    keys: list[PresharedKey] = []
    lines_of_secret: dict[bytes, int] = {}
    lines_of_name: dict[str, int] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split()
        if len(fields) > 2:
            raise InvalidKeyError(f"{source}, line {number}: expected 'NAME HEX' or 'HEX'")
        name, hexkey = (fields[0], fields[1]) if len(fields) == 2 else ("", fields[0])
        try:
            secret = bytes.fromhex(hexkey)
        except ValueError:
            raise InvalidKeyError(f"{source}, line {number}: the key is not hexadecimal") from None
        try:
            key = PresharedKey(secret, name)
        except InvalidKeyError as exc:
            raise InvalidKeyError(f"{source}, line {number}: {exc}") from None
        # One key, one master: the same secret under two names would let either name open the
        # other's sessions, and a name twice would make --key-name ambiguous.
        if secret in lines_of_secret:
            raise InvalidKeyError(
                f"{source}, line {number}: the same key as line {lines_of_secret[secret]}; "
                "give each master a key of its own (tdtp keygen)"
            )
        if name and name in lines_of_name:
            raise InvalidKeyError(
                f"{source}, line {number}: the name {name!r} is already used on line "
                f"{lines_of_name[name]}"
            )
        lines_of_secret[secret] = number
        if name:
            lines_of_name[name] = number
        keys.append(key)
    if not keys:
        raise InvalidKeyError(f"{source} holds no key (generate one with: tdtp keygen FILE)")
    return keys


def load_keys(path: str | os.PathLike[str]) -> list[PresharedKey]:
    """Read every key of a key file, for a slave: ``tdtp.listen(..., keys=tdtp.load_keys(path))``
    (a master presents one: :func:`load_key`). Refuses a file that other users may read: the keys
    are the secret."""
    file = Path(path)
    try:
        mode = file.stat().st_mode
        text = file.read_text(encoding="utf-8")
    except OSError as exc:
        raise InvalidKeyError(f"cannot read key file {file}: {exc.strerror}") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise InvalidKeyError(
            f"key file {file} is readable by other users; restrict it with: chmod 600 {file}"
        )
    return parse_keys(text, str(file))


def choose_key(keys: list[PresharedKey], name: str | None, source: str) -> PresharedKey:
    """The key a master presents: the first of ``keys``, or the one called ``name``."""
    if name is None:
        return keys[0]
    for key in keys:
        if key.name == name:
            return key
    known = ", ".join(key.label for key in keys)
    raise InvalidKeyError(f"no key named {name!r} in {source} (it has: {known})")


def load_key(path: str | os.PathLike[str], name: str | None = None) -> PresharedKey:
    """Read the key a master presents from a key file: its first key, or the one called ``name``
    (as ``tdtp master --key-file FILE [--key-name NAME]``). For ``tdtp.connect(..., key=...)``;
    a slave takes every key of its file: ``tdtp.listen(..., keys=tdtp.load_keys(path))``."""
    return choose_key(load_keys(path), name, str(path))


def format_keys(keys: list[PresharedKey]) -> str:
    """``keys`` in the key file format, one ``NAME HEX`` (or ``HEX``) line each."""
    lines = ["# tdtp pre-shared keys: NAME HEX (keep this file secret)"]
    lines += [f"{key.name} {key.secret.hex()}" if key.name else key.secret.hex() for key in keys]
    return "\n".join(lines) + "\n"


def write_key_file(path: str | os.PathLike[str], keys: list[PresharedKey]) -> None:
    """Write ``keys`` to a new file readable by its owner only (an existing file is not replaced)."""
    file = Path(path)
    try:
        descriptor = os.open(file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise InvalidKeyError(f"{file} exists; choose another name or delete it first") from None
    except OSError as exc:
        raise InvalidKeyError(f"cannot create key file {file}: {exc.strerror}") from None
    with os.fdopen(descriptor, "w", encoding="utf-8") as out:
        out.write(format_keys(keys))
