"""The command line's keys: ``--key-file`` / ``--keyed`` on the session commands, and ``tdtp keygen``.

A master reads its key from ``--key-file`` (the first key, or the one ``--key-name`` names); a slave
accepts every key in its file, one per master; ``tdtp demo --keyed`` pairs its master and slave with a
key generated for the run, and ``tdtp demo --key-file F`` with the first key of F.
"""

from __future__ import annotations

import argparse
import ipaddress
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from tdtp.errors import InvalidKeyError
from tdtp.protection.key_file import choose_key, load_keys, write_key_file
from tdtp.protection.keys import KeyRing, PresharedKey


class KeyArgumentError(Exception):
    """A key option the command cannot use; the message is the one line to print."""


def add_key_arguments(parser: argparse.ArgumentParser, *, demo: bool = False) -> None:
    group = parser.add_argument_group(
        "keys",
        "pre-shared keys (tdtp keygen FILE): every datagram authenticated, payloads encrypted",
    )
    group.add_argument(
        "--key-file",
        metavar="FILE",
        help="keys, one 'NAME HEX' per line: a master uses one, a slave accepts them all",
    )
    group.add_argument(
        "--key-name", metavar="NAME", help="master: the key of FILE to use (default: the first)"
    )
    group.add_argument(
        "--no-encrypt",
        action="store_true",
        help="keyed sessions: authenticate payloads without encrypting them",
    )
    if demo:
        group.add_argument(
            "--keyed",
            action="store_true",
            help="pair master and slave with a key made for this run",
        )


@dataclass(frozen=True)
class SessionKeys:
    """What the command's endpoints get: the master's key and the slave's ring (or neither)."""

    master: PresharedKey | None = None
    slave: KeyRing | None = None

    @property
    def keyed(self) -> bool:
        return self.master is not None or self.slave is not None


def session_keys(args: argparse.Namespace) -> SessionKeys:
    """The keys ``args`` ask for; raises :class:`KeyArgumentError` with a one-line reason."""
    path: str | None = getattr(args, "key_file", None)
    if getattr(args, "keyed", False):
        if path is not None:
            raise KeyArgumentError("give --keyed or --key-file, not both")
        key = PresharedKey.generate("demo")
        return SessionKeys(key, KeyRing([key]))
    if path is None:
        if getattr(args, "key_name", None) is not None:
            raise KeyArgumentError("--key-name needs --key-file")
        return SessionKeys()
    try:
        keys = load_keys(path)
        ring = KeyRing(keys)
    except InvalidKeyError as exc:
        raise KeyArgumentError(str(exc)) from None
    try:
        master = choose_key(keys, getattr(args, "key_name", None), path)
    except InvalidKeyError as exc:
        raise KeyArgumentError(str(exc)) from None
    return SessionKeys(master, ring)


def warn_if_exposed(host: str, keys: SessionKeys) -> None:
    """An unkeyed slave on a non-loopback address: say once that anyone can command it."""
    if keys.keyed:
        return
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = host == "localhost"
    if not loopback:
        print(
            f"tdtp: warning: this slave is unkeyed and listens on {host}: anyone who can reach the "
            "port can command it (pair it with a key: tdtp keygen FILE, then --key-file FILE)",
            file=sys.stderr,
        )


def keygen_main(argv: Sequence[str]) -> int:
    """``tdtp keygen FILE [--name NAME ...]``: write new random keys to a new file."""
    parser = argparse.ArgumentParser(
        prog="tdtp keygen",
        description="Write new random 32-byte pre-shared keys to a new file (mode 600).",
    )
    parser.add_argument("file", help="the key file to create")
    parser.add_argument(
        "--name",
        action="append",
        default=[],
        help="a name for the key (repeat for one key per master; default: one unnamed key)",
    )
    args = parser.parse_args(list(argv))
    try:
        keys = [PresharedKey.generate(name) for name in args.name] or [PresharedKey.generate()]
        write_key_file(args.file, keys)
    except InvalidKeyError as exc:
        print(f"tdtp keygen: {exc}", file=sys.stderr)
        return 2
    for key in keys:
        print(f"{args.file}: key {key.label} (id {key.key_id.hex()})")
    return 0
