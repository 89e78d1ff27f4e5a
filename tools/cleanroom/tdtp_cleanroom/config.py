"""Configuration: the defaults of PROTOCOL.md (as tests/vectors/README.md lists them)."""

from __future__ import annotations

from dataclasses import dataclass, field

Addr = tuple[str, int]


@dataclass
class Config:
    # the session
    max_payload: int = 1200
    min_peer_payload: int = 1
    separate_acks: bool = False
    ack_size: int = 5
    ack_delay: float = 0.020
    silence_timeout: float = 0.100
    keepalive_interval: float | None = None  # a third of silence_timeout unless given (5.2)
    idle_timeout: float = 30.0
    initial_rtt: float = 0.100
    reorder_threshold: int = 3
    open_retry_interval: float = 0.25
    open_timeout: float = 5.0
    # keyed
    psk: bytes | None = None  # a master's key
    psks: list[bytes] = field(default_factory=list)  # a slave's ring, in ring order
    suite: int = 1
    encrypt: bool = True
    takeover: bool = False
    # the control channel (5.10)
    control_window: int = 64
    control_max_message: int = 256
    control_max_rate: float = 200.0
    control_burst: int = 8
    control_timeout: float = 20.0
    # send timestamps (5.13): a master with an interval sets TIMESTAMPS (not with multipath)
    timestamp_interval: float = 0.0
    # admission (5.1 rule 2) and the slave's budgets
    cookie_lifetime: float = 5.0
    opens_per_source: float = 20.0
    opens_burst: float = 40.0
    max_sources: int = 4096
    replies_per_second: float = 20000.0
    resets_per_second: float = 1000.0
    # a server (5.1 "A server with several masters", 5.8, 5.9)
    max_peers: int = 4
    source_share: float = 0.5
    reclaim_after: float = 10.0
    exclusive: bool = False
    takeover_after: int = 3
    migration_quiet: float = 0.005
    migration_trials_per_second: float = 2000.0
    challenges_per_second: float = 10.0
    challenge_burst: float = 3.0
    path_response_interval: float = 0.005
    # multipath (section 5.11): a master with `multipath` sets the OPEN flag; a slave always takes
    # part in a multipath session its master asks for
    multipath: bool = False
    max_paths: int = 4
    new_paths_per_second: float = 10.0
    validation_timeout: float = 3.0
    failed_probe_interval: float = 0.2
    probe_interval: float = 0.020
    path_timeout: float = 0.060
    report_interval: float = 0.010

    @property
    def keepalive(self) -> float:
        return (
            self.keepalive_interval
            if self.keepalive_interval is not None
            else self.silence_timeout / 3
        )

    @property
    def max_opens(self) -> int:
        return min(int(self.open_timeout / self.open_retry_interval + 1e-9), 65536)

    @property
    def largest_datagram(self) -> int:
        """Row 4 of section 5.5: 5 + max(max_payload + 5, 64, 21 + control_max_message) + 18."""
        return 5 + max(self.max_payload + 5, 64, 21 + self.control_max_message) + 18
