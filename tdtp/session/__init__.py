"""The sans-IO session core: one TDTP session between a master and a slave, with no sockets and no clock.

* :mod:`tdtp.session.connection`: :class:`~tdtp.session.connection.Connection`, the state machine the
  asyncio endpoints, the impairment emulator and the simulator all drive;
* :mod:`tdtp.session.events`: what a connection reports (:class:`DataReceived`, :class:`PeerSilent`, ...);
* :mod:`tdtp.session.stats`: its counters (:class:`ConnectionStats`, drops by reason);
* :mod:`tdtp.session.sent_log`, :mod:`tdtp.session.receive_window`: the sender's record of what left and
  the receiver's record of what arrived, from which the piggybacked acknowledgements are built and read;
* :mod:`tdtp.session.rtt`, :mod:`tdtp.session.loss_rate`: the RTT estimator and the loss-event rate;
* :mod:`tdtp.session.sample_age`: the delivered samples' ages, in a fixed log histogram;
* :mod:`tdtp.session.delivery`, :mod:`tdtp.session.reorder_buffer`: what reaches the application, in
  sequence order through the adaptive reorder wait, with its send time or estimated age;
* the pieces of a connection that own state, each in its module: :mod:`~tdtp.session.handshake` (the
  opening), :mod:`~tdtp.session.liveness` (keep-alive, watchdog and idle clocks),
  :mod:`~tdtp.session.recovery` (loss recovery), :mod:`~tdtp.session.ack_scheduler` (the ACKs owed),
  :mod:`~tdtp.session.sender` (the sample waiting to leave), :mod:`~tdtp.session.outbox` (what leaves),
  :mod:`~tdtp.session.control_channel` (the reliable, ordered control messages beside the samples),
  :mod:`~tdtp.session.event_queue` (the bounded event queue), :mod:`~tdtp.session.timer_hint`,
  :mod:`~tdtp.session.reset_guard` (a master's recent datagrams, which a RESET must echo),
  :mod:`~tdtp.session.path` (the peer's address: validated, or under the 3x amplification limit),
  :mod:`~tdtp.session.multipath` (a multipath session's paths, scheduler and per-path congestion
  control);
* :mod:`tdtp.session.state`: :class:`State`, where a session is in its life;
* :mod:`tdtp.session.view`: :class:`~tdtp.session.view.ConnectionView`, the connection's read-only
  properties (its base class).

Nothing here imports asyncio, the command line, the emulator or the simulator, or reads a clock
(docs/ARCHITECTURE.md; ``tests/test_layering.py`` enforces it). This package's ``__init__`` imports
nothing, so that importing one piece never drags in the rest.
"""
