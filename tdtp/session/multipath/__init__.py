"""Multipath: one session over several paths at once (docs/PROTOCOL.md 5.11, docs/CONTROL.md 11).

* :mod:`~tdtp.session.multipath.paths`: :class:`Multipath`, the session's paths and the one object
  a connection talks to (its seam: ``admits``, ``intercept``, ``route``, ``deadline``,
  ``on_timer``);
* :mod:`~tdtp.session.multipath.path`: one path: its validation, amplification budget and figures;
* :mod:`~tdtp.session.multipath.scheduler`: which paths a sample goes on (redundant, adaptive);
* :mod:`~tdtp.session.multipath.congestion`: each path's rate controller, and which paths share a
  bottleneck;
* :mod:`~tdtp.session.multipath.copies`: the receiver's memory of first copies, the sender's of
  where each sample went.

Like the rest of the session core: no sockets, no clock. This ``__init__`` imports nothing.
"""
