"""What teleoperation applications put inside TDTP's datagrams: sample formats above the transport.

* :mod:`tdtp.teleop.haptic_sample`: the demo's 36-byte haptic record (send time, position, force).
"""
