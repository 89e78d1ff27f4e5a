"""The models and plumbing of ``benchmarks/closed_loop.py``: a bilateral teleoperation loop to measure
transports with, not library code (tdtp's users bring their own robot and operator).

* ``workspace``: the task's geometry and control period, shared by both sides.
* ``arm.xml``, ``arm``: the slave, a MuJoCo two-link arm and its task-space position controller; the
  contact force it measures against a stiff wall.
* ``operator_model``: the master, an operator's hand (an impedance following a seeded reach, press and
  slide motion) holding a haptic device that renders the force sent back.
* ``passivity``: a passivity observer for the channel (time-domain passivity approach).
* ``transports``: tdtp, raw UDP, TCP and Zenoh behind one channel interface, and their registry.
* ``tcp_link``, ``relays``: the impairment for the transports without tdtp's in-process netem.
* ``sides``: each side's 1 kHz loop, run in its own process.
* ``metrics``: the figures of a run, from both sides' logs.
"""
