"""The ``tdtp`` command: ``tdtp demo``, ``tdtp master HOST:PORT``, ``tdtp slave --port N``.

A master sends position samples (a circle traced at 0.5 Hz) at ``--rate`` per second; the slave answers
each period with force feedback from a virtual spring wall. Both print a live status block once per second,
or with ``--json`` one JSON object at the end. Ctrl-C ends a run early and still prints the summary.

Exit status: 0 when the run ended as asked, 1 when the session failed (no slave, refused, lost after a
silence longer than the outage limit, evicted), 2 for a usage error (one line on stderr saying what to
change), 130 after Ctrl-C, 143 after SIGTERM (a service manager's stop: handled as Ctrl-C is, so a slave
still tells its masters whether it will be back, ``--on-stop``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import sys
from collections.abc import Callable, Coroutine, Sequence
from typing import Any

from tdtp.aio.timer import check_timer_preference
from tdtp.capture.pcap import CaptureError
from tdtp.cli.bandwidth import bandwidth_main
from tdtp.cli.demo import demo_table, run_demo
from tdtp.cli.keys import (
    KeyArgumentError,
    keygen_main,
    session_keys,
)
from tdtp.cli.master import run_master
from tdtp.cli.netem_relay import run_relay
from tdtp.cli.options import UsageError, build_parser, rendezvous_settings, session_config
from tdtp.cli.outcome import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED, Outcome
from tdtp.cli.parser import EXIT_USAGE
from tdtp.cli.relay import run_rendezvous_relay
from tdtp.cli.simulate import simulate_main
from tdtp.cli.slave import run_slave
from tdtp.cli.summary import summary_text
from tdtp.errors import (
    AddressError,
    ArgumentTypeError,
    ConnectError,
    InvalidArgumentError,
    PayloadTooLargeError,
    TdtpError,
)


def _loop_factory(choice: str) -> Callable[[], asyncio.AbstractEventLoop] | None:
    if choice == "asyncio":
        return None
    try:
        import uvloop  # noqa: PLC0415 -- optional (the "fast" extra): imported only when wanted
    except ImportError:
        if choice == "uvloop":
            raise UsageError(
                "--loop uvloop: uvloop is not installed (pip install 'tdtp[fast]')"
            ) from None
        return None
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


Runner = Callable[[argparse.Namespace, Outcome], Coroutine[Any, Any, None]]
RUNNERS: dict[str, Runner] = {
    "demo": run_demo,
    "master": run_master,
    "slave": run_slave,
    "netem-relay": run_relay,
    "relay": run_rendezvous_relay,
}
_USAGE_ERRORS = (
    UsageError,
    KeyArgumentError,
    CaptureError,
    InvalidArgumentError,
    ArgumentTypeError,
    AddressError,
    PayloadTooLargeError,
)
"""Errors that a different command line fixes: exit status 2."""


def check_command_line(args: argparse.Namespace) -> None:
    """What argparse cannot say: which ways to find the peer go together."""
    meet = getattr(args, "rendezvous", None) is not None
    if args.command == "master":
        ways = [args.address is not None, args.listen is not None, meet]
        if sum(ways) != 1:
            raise UsageError(
                "give the slave's HOST:PORT to dial it, --listen PORT to let it dial this master, "
                "or --rendezvous HOST:PORT to meet it at a relay (one of the three)"
            )
    if args.command == "slave":
        if args.connect is not None and meet:
            raise UsageError("give --connect HOST:PORT or --rendezvous HOST:PORT, not both")
        if args.port is None and args.connect is None and not meet:
            raise UsageError(
                "give --port N to listen, --connect HOST:PORT to dial the master, or "
                "--rendezvous HOST:PORT to meet it at a relay"
            )
    if meet and args.command in ("demo", "master", "slave"):
        if getattr(args, "netem", None) or getattr(args, "netem_ms", None) or args.pcap:
            raise UsageError("--netem and --pcap are not available with --rendezvous")
        if getattr(args, "path", None) or getattr(args, "local_address", None):
            raise UsageError(
                "--rendezvous meets the peer on one socket: not with --path or --local-address"
            )
        rendezvous_settings(args)
        unkeyed = getattr(args, "key_file", None) is None and not getattr(args, "keyed", False)
        if unkeyed and args.rendezvous_name is None and args.command != "demo":
            raise UsageError(
                "an unkeyed --rendezvous needs --rendezvous-name NAME (the same on both "
                "sides); with --key-file the name is derived from the key"
            )


async def _run(runner: Runner, args: argparse.Namespace, outcome: Outcome) -> None:
    """``runner`` with SIGTERM handled as asyncio.Runner handles SIGINT: the run's task is
    cancelled, so that it ends as after Ctrl-C (CLOSEs sent, summary printed)."""
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None

    def terminate() -> None:
        outcome.terminated = True
        task.cancel()

    # Not in the main thread, or no signals here: SIGTERM keeps its default.
    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
        loop.add_signal_handler(signal.SIGTERM, terminate)
    try:
        await runner(args, outcome)
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.remove_signal_handler(signal.SIGTERM)


def _fail(message: object, status: int) -> int:
    print(f"tdtp: {message}", file=sys.stderr)
    return status


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(sys.argv[1:] if argv is None else argv)
    if arguments[:1] == ["simulate"]:
        # Its own parser (tdtp.cli.simulate); the subcommand below only lists it in --help.
        return simulate_main(arguments[1:])
    if arguments[:1] == ["keygen"]:
        return keygen_main(arguments[1:])
    if arguments[:1] == ["bandwidth"]:
        return bandwidth_main(arguments[1:])
    args = build_parser().parse_args(arguments)  # exits 2 with argparse's message on its own
    try:
        check_command_line(args)
        if args.command in ("demo", "master", "slave"):
            args.session_keys = session_keys(args)
        if hasattr(args, "timer"):
            check_timer_preference(args.timer)
        if hasattr(args, "controller"):
            session_config(args)
        loop_factory = _loop_factory(args.loop)
    except (*_USAGE_ERRORS, TdtpError) as exc:
        return _fail(exc, EXIT_USAGE)
    outcome = Outcome()
    interrupted = False
    try:
        with asyncio.Runner(loop_factory=loop_factory) as runner:
            runner.run(_run(RUNNERS[args.command], args, outcome))
    except KeyboardInterrupt:
        interrupted = True
    except asyncio.CancelledError:
        if not outcome.terminated:
            raise
    except _USAGE_ERRORS as exc:
        return _fail(exc, EXIT_USAGE)
    except (ConnectError, TdtpError, OSError) as exc:
        return _fail(exc, EXIT_FAILED)
    if outcome.summary is not None:
        try:
            if args.json or args.command in ("netem-relay", "relay"):
                print(json.dumps(outcome.summary, indent=2))
            elif args.command == "demo":
                print(demo_table(outcome.summary))
            else:
                print(summary_text(outcome.summary))
            sys.stdout.flush()
        except BrokenPipeError:  # `tdtp ... | head`: the reader has what it wanted
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    if outcome.terminated:
        return EXIT_TERMINATED
    if interrupted:
        return EXIT_INTERRUPTED
    if outcome.failure is not None:
        return _fail(outcome.failure, outcome.status)
    return outcome.status


if __name__ == "__main__":
    sys.exit(main())
