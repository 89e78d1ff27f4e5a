"""tests/netlab.py, the namespaces of the kernel tests and benchmarks: a lab's veth carries datagrams
between its namespaces, closing it leaves no namespace and no process behind, and a lab whose process
was killed before it could close is swept by the next one, while a live lab's namespaces are not.
Skipped without root or ``ip``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import netlab
import pytest
from netlab import NetLab

pytestmark = pytest.mark.skipif(netlab.missing() is not None, reason=str(netlab.missing()))

LISTEN = (
    "import socket\n"
    "s=socket.socket(socket.AF_INET,socket.SOCK_DGRAM);s.bind(('10.203.0.2',7999));s.settimeout(10)\n"
    "print('ready',flush=True);print(s.recvfrom(100)[0].decode(),flush=True)\n"
)
SEND = "import socket;socket.socket(socket.AF_INET,socket.SOCK_DGRAM).sendto(b'hi',('10.203.0.2',7999))"


def _gone(pid: int) -> bool:
    """No such process, or one that has died and waits to be reaped."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in "ZX"
    except FileNotFoundError:
        return True


def test_a_lab_carries_datagrams_and_leaves_nothing_behind() -> None:
    with NetLab("tdtptest") as lab:
        lab.add("a")
        lab.add("b")
        lab.veth("a", "a0", "b", "b0", a_addr="10.203.0.1/24", b_addr="10.203.0.2/24")
        listener = lab.spawn("b", sys.executable, "-c", LISTEN)
        assert listener.stdout is not None
        assert listener.stdout.readline().strip() == "ready"
        lab.python("a", SEND, timeout=10)
        assert listener.stdout.readline().strip() == "hi"
        sleeper = lab.spawn("a", "sleep", "60")
        assert sorted(lab.left()) == sorted([lab.name("a"), lab.name("b")])
    assert lab.left() == []
    assert sleeper.returncode is not None  # killed, and reaped by close()
    with pytest.raises(netlab.NetLabError):  # its namespaces are gone
        lab.exec("a", "true")


def test_a_crashed_labs_namespaces_and_processes_are_swept_by_the_next_lab() -> None:
    tests = str(Path(__file__).resolve().parent)
    crashing = (
        f"import sys,time; sys.path.insert(0, {tests!r}); from netlab import NetLab\n"
        "lab = NetLab('tdtptest'); lab.add('x')\n"
        "inside = lab.spawn('x', 'sh', '-c', 'echo in; exec sleep 60'); inside.stdout.readline()\n"
        "print(lab.name('x'), flush=True); time.sleep(60)\n"
    )
    owner = subprocess.Popen([sys.executable, "-c", crashing], stdout=subprocess.PIPE, text=True)
    try:
        assert owner.stdout is not None
        left = owner.stdout.readline().strip()
        assert left.startswith("tdtptest-"), left
        inside = [int(pid) for pid in netlab.run("ip", "netns", "pids", left).split()]
        assert inside  # the sleep its lab started
        with NetLab("tdtptest") as lab:
            lab.add("y")  # the owner still runs: its namespace stays
            assert left in netlab.listed()
        owner.kill()
        owner.wait(timeout=10)
        assert left in netlab.listed()  # killed, it could not close its lab
        with NetLab("tdtptest") as lab:
            lab.add("y")
            assert left not in netlab.listed()
        assert all(_gone(pid) for pid in inside), inside
    finally:
        if owner.poll() is None:
            owner.kill()
            owner.wait(timeout=10)
        netlab.sweep()
