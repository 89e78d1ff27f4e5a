"""The argument parser every ``tdtp`` subcommand uses: a usage error is one line on stderr."""

from __future__ import annotations

import argparse
from typing import NoReturn

EXIT_USAGE = 2


class CommandParser(argparse.ArgumentParser):
    """argparse, but a usage error prints one line that says what to change (and where help is),
    not the whole usage block, and exits with status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: {message} (see {self.prog} --help)\n")
