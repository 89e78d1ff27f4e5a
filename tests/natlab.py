"""A small Internet in network namespaces, with the kernel's NAT (nft), for tests and benchmarks/nat.py.

Topology (every name unique to the run; nothing leaves the namespaces)::

    host-a 192.168.1.2 -- nat-a 192.168.1.1 | 203.0.113.1 --+
                                                            |  inet: a bridge, 203.0.113.0/24
    host-b 192.168.2.2 -- nat-b 192.168.2.1 | 203.0.113.2 --+-- relay 203.0.113.10
                                                            |
                                       (optional) public 203.0.113.20

Each site is a host behind its own NAT namespace. NAT kinds:

* ``"eim"``: ``masquerade`` (Linux keeps the source port when it can: endpoint-independent mapping,
  what most home routers do), with a stateful firewall on the WAN side (``ct state new`` dropped:
  nothing unsolicited gets in; replies and punched holes do);
* ``"symmetric"``: ``masquerade fully-random``: every new flow (destination) gets its own random
  port, so the address the relay sees is useless to the peer. :meth:`NatLab.mappings` proves it on
  the running kernel (two destinations, two ports);
* ``firewall=False``: no filter on the WAN: the NAT box answers a datagram to an unmapped port with
  ICMP port unreachable (what made ``tdtp master`` say "nothing listens" to a robot behind NAT).

:meth:`NatLab.cut` drops everything between two NATs' WAN addresses (the direct path dies, the relay
still works); :meth:`NatLab.flush_conntrack` forgets a NAT's mappings mid-session. The namespaces,
their links and processes are tests/netlab.py's: :meth:`NatLab.close` removes the namespaces and
kills the processes started in them (:meth:`NatLab.spawn`), whatever happened.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from typing import Literal

import netlab
from netlab import NetLab

NatKind = Literal["eim", "symmetric"]
RELAY_ADDR = "203.0.113.10"
PUBLIC_ADDR = "203.0.113.20"
NAT_MODES: dict[str, str] = {"eim": "masquerade", "symmetric": "masquerade fully-random"}


def missing() -> str | None:
    """Why this machine cannot build the lab, or None."""
    return netlab.missing("nft", "conntrack")


@dataclass
class Site:
    name: str
    index: int
    nat: NatKind | None
    host_ns: str
    nat_ns: str | None
    host_addr: str
    wan_addr: str
    """The address the Internet sees (the NAT's WAN address; the host's own without a NAT)."""


class NatLab(NetLab):
    """The namespaces; build with :meth:`add_site` after :meth:`open`, always :meth:`close`."""

    def __init__(self) -> None:
        super().__init__("tdtpnat")
        self.sites: dict[str, Site] = {}

    def open(self, *, public_host: bool = False) -> NatLab:
        self.add("inet")
        self.exec("inet", "ip", "link", "add", "br0", "type", "bridge")
        self.link("inet", "br0", up=True)
        # The Internet's own filter (empty): cut() adds its drops here.
        self.nft("inet", "add table bridge lab")
        # Counters first (priority -10), then the cuts: traffic() sees what was sent, cut or not.
        self.nft("inet", "add chain bridge lab seen { type filter hook forward priority -10 ; }")
        self.nft("inet", "add chain bridge lab cuts { type filter hook forward priority 0 ; }")
        self._leaf("relay", RELAY_ADDR)
        if public_host:
            self._leaf("public", PUBLIC_ADDR)
        return self

    def _bridged(self, role: str, dev: str, port: str, addr: str | None) -> None:
        """A veth from ``role``'s ``dev`` to a port of the Internet's bridge."""
        self.veth(role, dev, "inet", port, a_addr=addr)
        self.exec("inet", "ip", "link", "set", port, "master", "br0")

    def _leaf(self, role: str, addr: str) -> str:
        ns = self.add(role)
        self._bridged(role, "eth0", f"p{role[:5]}", f"{addr}/24")
        return ns

    def add_site(self, name: str, nat: NatKind | None, *, firewall: bool = True) -> Site:
        index = len(self.sites) + 1
        wan = f"203.0.113.{index}"
        if nat is None:
            host_ns = self._leaf(f"h{name}", wan)
            site = Site(name, index, None, host_ns, None, wan, wan)
            self.sites[name] = site
            return site
        host, nat_role = f"h{name}", f"n{name}"
        host_ns, nat_ns = self.add(host), self.add(nat_role)
        lan_gw, lan_host = f"192.168.{index}.1", f"192.168.{index}.2"
        self.veth(host, "eth0", nat_role, "lan", a_addr=f"{lan_host}/24", b_addr=f"{lan_gw}/24")
        self._bridged(nat_role, "wan", f"pn{name}", f"{wan}/24")
        self.route(host, lan_gw)
        self.forward(nat_role)
        rules = [
            "add table ip nat",
            "add chain ip nat postrouting_nat { type nat hook postrouting priority 100 ; }",
            f'add rule ip nat postrouting_nat oifname "wan" {NAT_MODES[nat]}',
        ]
        if firewall:
            rules += [
                "add table inet fw",
                "add chain inet fw forward_wan { type filter hook forward priority 0 ; }",
                'add rule inet fw forward_wan iifname "wan" ct state new drop',
                "add chain inet fw input_wan { type filter hook input priority 0 ; }",
                'add rule inet fw input_wan iifname "wan" ct state new drop',
            ]
        for rule in rules:
            self.nft(nat_role, rule)
        site = Site(name, index, nat, host_ns, nat_ns, lan_host, wan)
        self.sites[name] = site
        return site

    def count(self, name: str, src: str, dst: str) -> None:
        """Count the packets from ``src`` to ``dst`` crossing the Internet as ``name``."""
        self.nft(
            "inet",
            f'add rule bridge lab seen ip saddr {src} ip daddr {dst} counter comment "{name}"',
        )

    def counters(self) -> dict[str, int]:
        """Packets counted by :meth:`count`, by name (added up over rules of one name)."""
        text = self.exec("inet", "nft", "-j", "list", "chain", "bridge", "lab", "seen")
        found: dict[str, int] = {}
        for item in json.loads(text)["nftables"]:
            rule = item.get("rule")
            if rule is None:
                continue
            for expr in rule["expr"]:
                if "counter" in expr:
                    name = rule.get("comment", "")
                    found[name] = found.get(name, 0) + int(expr["counter"]["packets"])
        return found

    def wait_for_traffic(self, name: str, packets: int, patience: float = 30.0) -> None:
        """Until ``packets`` more packets were counted as ``name`` (bounded by ``patience``)."""
        start = self.counters().get(name, 0)
        give_up = time.monotonic() + patience
        while self.counters().get(name, 0) - start < packets:
            if time.monotonic() > give_up:
                raise AssertionError(f"fewer than {packets} {name} packets in {patience:g} s")
            time.sleep(0.05)

    def nft(self, role: str, rule: str) -> None:
        self.exec(role, "nft", rule)

    def cut(self, a: str, b: str) -> None:
        """Drop everything between two sites' WAN addresses (their direct path); the relay
        still reaches both."""
        wa, wb = self.sites[a].wan_addr, self.sites[b].wan_addr
        for src, dst in ((wa, wb), (wb, wa)):
            self.nft("inet", f"add rule bridge lab cuts ip saddr {src} ip daddr {dst} drop")

    def heal(self) -> None:
        """Undo every :meth:`cut`."""
        self.nft("inet", "flush chain bridge lab cuts")

    def flush_conntrack(self, site: str) -> None:
        """The NAT forgets every mapping (a router reboot, a carrier's mapping expiring)."""
        assert self.sites[site].nat_ns is not None
        self.exec(f"n{site}", "conntrack", "-F", check=False)

    def mappings(self, site: str) -> tuple[int, int]:
        """The source ports two destinations (the relay and the public host) see from one socket of
        ``site``'s host: equal behind an endpoint-independent NAT, different behind a symmetric
        one. Needs ``open(public_host=True)``."""
        listen = (
            "import socket,sys\n"
            "s=socket.socket(socket.AF_INET,socket.SOCK_DGRAM);s.bind(('0.0.0.0',7999));"
            "s.settimeout(5)\n"
            "d,a=s.recvfrom(100);print(a[1])\n"
        )
        seen = [self.spawn(role, sys.executable, "-c", listen) for role in ("relay", "public")]
        send = (
            "import socket,time\n"
            "s=socket.socket(socket.AF_INET,socket.SOCK_DGRAM)\n"
            f"for _ in range(10):\n"
            f"  s.sendto(b'x',('{RELAY_ADDR}',7999));s.sendto(b'x',('{PUBLIC_ADDR}',7999))\n"
            "  time.sleep(0.02)\n"
        )
        self.python(f"h{site}", send)
        ports = []
        for process in seen:
            out, _ = process.communicate(timeout=10)
            ports.append(int(out.strip()))
        return ports[0], ports[1]
