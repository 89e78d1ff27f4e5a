"""Network namespaces for the kernel tests and benchmarks: made, wired, used and removed in one place.

A :class:`NetLab` makes namespaces whose names carry a tag unique to it (``PURPOSE-PID-HEX-ROLE``,
e.g. ``tdtpk-4242-a1b2c3-r``), joins them with veth pairs (each end created inside its namespace,
so no name ever exists in the host's), puts qdiscs on their devices, and runs commands in them:
:meth:`~NetLab.exec` waits (bounded) for a command's output, :meth:`~NetLab.python` for this
interpreter's, :meth:`~NetLab.spawn` starts one and keeps its handle. :meth:`~NetLab.close` (also the
end of a ``with`` block) kills those processes and anything else left in the lab's namespaces, then
deletes the namespaces. A lab that never got to close (its process killed) is swept by the next lab
made on the machine: a tagged namespace whose PID no longer runs is removed then, its processes with
it; a live process's namespaces are never touched.

Used by tests/natlab.py (the NAT lab), tests/test_multipath_netns.py and
benchmarks/kernel_bottleneck.py (which put tests/ on ``sys.path``, as benchmarks/nat.py does). Only
the kernel's own tools run (``ip``, ``tc``, and whatever a caller names); nothing leaves the
namespaces unless a caller routes it out.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
from typing import Self

PACKAGES = {"ip": "iproute2", "tc": "iproute2", "nft": "nftables"}
"""The Debian package of a tool, where it is not named for it."""
TAGGED = re.compile(r"^(tdtp[a-z]*)-(\d+)-[0-9a-f]{6}-")
"""A lab's namespace: purpose, owner PID, random part, then the role."""


class NetLabError(RuntimeError):
    """A command the lab ran failed (its stderr, or its status, is the message)."""


def missing(*tools: str) -> str | None:
    """Why this machine cannot make a lab that uses ``tools`` (``ip`` always), or None: a skip
    reason for a test, a one-line excuse for a benchmark."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "needs root (network namespaces)"
    for tool in dict.fromkeys(("ip", *tools)):
        if shutil.which(tool) is None:
            return f"needs {tool!r} on PATH (apt-get install {PACKAGES.get(tool, tool)})"
    return None


def run(*command: str, timeout: float = 10.0, check: bool = True) -> str:
    """``command``'s stdout; :class:`NetLabError` when it fails (unless not ``check``) or outlasts
    ``timeout`` seconds."""
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        raise NetLabError(f"{' '.join(command)[:200]}: no answer within {timeout:g} s") from None
    if check and done.returncode != 0:
        why = done.stderr.strip()[-800:] or done.returncode
        raise NetLabError(f"{' '.join(command)[:200]}: {why}")
    return done.stdout


def listed() -> list[str]:
    """Every network namespace's name on the machine (``ip netns list``)."""
    return [line.split()[0] for line in run("ip", "netns", "list").splitlines() if line.strip()]


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove(name: str) -> None:
    """Kill what still runs in namespace ``name`` (ours: made by a lab), then delete it."""
    with contextlib.suppress(NetLabError):
        for pid in run("ip", "netns", "pids", name).split():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(int(pid), signal.SIGKILL)
    run("ip", "netns", "del", name, check=False)


def sweep() -> list[str]:
    """Remove the namespaces of labs whose process is gone (killed before it could close); the
    names removed."""
    gone = []
    for name in listed():
        found = TAGGED.match(name)
        if found is not None and not _running(int(found.group(2))):
            _remove(name)
            gone.append(name)
    return gone


class NetLab:
    """Namespaces tagged ``PURPOSE-PID-HEX``; build with :meth:`add` and :meth:`veth`, always
    :meth:`close` (or use ``with``)."""

    def __init__(self, purpose: str = "tdtplab") -> None:
        if not re.fullmatch(r"tdtp[a-z]*", purpose):
            raise ValueError(f"purpose: 'tdtp' and lower-case letters, got {purpose!r}")
        self.tag = f"{purpose}-{os.getpid()}-{secrets.token_hex(3)}"
        self.created: list[str] = []
        self.processes: list[subprocess.Popen[str]] = []
        self._swept = False

    def name(self, role: str) -> str:
        """The namespace of ``role`` in this lab."""
        return f"{self.tag}-{role}"

    def add(self, role: str) -> str:
        """A namespace for ``role`` with its loopback up; its name. The first also sweeps away
        what crashed labs left."""
        if not self._swept:
            self._swept = True
            sweep()
        name = self.name(role)
        run("ip", "netns", "add", name)
        self.created.append(name)
        run("ip", "-n", name, "link", "set", "lo", "up")
        return name

    def veth(
        self,
        a: str,
        a_dev: str,
        b: str,
        b_dev: str,
        *,
        a_addr: str | None = None,
        b_addr: str | None = None,
    ) -> None:
        """A veth pair, ``a_dev`` in role ``a``'s namespace and ``b_dev`` in ``b``'s, both up, each
        with its address (``10.0.0.1/24``) when given."""
        run("ip", "link", "add", a_dev, "netns", self.name(a), "type", "veth", "peer", "name",
            b_dev, "netns", self.name(b))  # fmt: skip
        for role, dev, addr in ((a, a_dev, a_addr), (b, b_dev, b_addr)):
            if addr is not None:
                run("ip", "-n", self.name(role), "addr", "add", addr, "dev", dev)
            self.link(role, dev, up=True)

    def link(self, role: str, dev: str, *, up: bool) -> None:
        """Set device ``dev`` of ``role`` up or down."""
        run("ip", "-n", self.name(role), "link", "set", dev, "up" if up else "down")

    def route(self, role: str, via: str) -> None:
        """``role``'s default route, through ``via``."""
        run("ip", "-n", self.name(role), "route", "add", "default", "via", via)

    def forward(self, role: str) -> None:
        """``role`` forwards IPv4 (a router)."""
        self.exec(role, "sysctl", "-q", "-w", "net.ipv4.ip_forward=1")

    def qdisc(self, role: str, dev: str, *spec: str) -> None:
        """``tc qdisc add dev DEV root SPEC...`` in ``role`` (``"tbf", "rate", "1mbit", ...``)."""
        self.exec(role, "tc", "qdisc", "add", "dev", dev, "root", *spec)

    def exec(self, role: str, *command: str, timeout: float = 10.0, check: bool = True) -> str:
        """Run ``command`` in ``role``'s namespace; its stdout (see :func:`run`)."""
        return run("ip", "netns", "exec", self.name(role), *command, timeout=timeout, check=check)

    def python(self, role: str, code: str, *args: str, timeout: float = 30.0) -> str:
        """Run ``code`` with this interpreter in ``role``'s namespace; its stdout."""
        return self.exec(role, sys.executable, "-c", code, *args, timeout=timeout)

    def spawn(
        self, role: str, *command: str, env: dict[str, str] | None = None
    ) -> subprocess.Popen[str]:
        """Start ``command`` in ``role``'s namespace (stdout and stderr piped, text), with ``env``
        added to ours; :meth:`close` kills it if it still runs."""
        process = subprocess.Popen(
            ["ip", "netns", "exec", self.name(role), *command],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **(env or {})},
        )
        self.processes.append(process)
        return process

    def left(self) -> list[str]:
        """This lab's namespaces that exist on the machine (none after :meth:`close`)."""
        return [name for name in listed() if name.startswith(f"{self.tag}-")]

    def close(self) -> None:
        """Kill the processes :meth:`spawn` started (by their handles) and whatever else runs in
        the lab's namespaces, then delete them. Safe to call twice."""
        for process in self.processes:
            if process.poll() is None:
                process.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.communicate(timeout=5)
        self.processes.clear()
        for name in reversed(self.created):
            _remove(name)
        self.created.clear()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
