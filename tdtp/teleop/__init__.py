"""What teleoperation applications put inside TDTP's datagrams: sample formats above the transport.

* :mod:`tdtp.teleop.schema`: typed samples, a dataclass to bytes and back (:class:`SampleCodec`);
* :mod:`tdtp.teleop.deadband`: perceptual deadband, send a sample only when the change would be felt
  (:class:`DeadbandSender`, :class:`DeadbandReceiver`);
* :mod:`tdtp.teleop.haptic_sample`: the demo's 36-byte haptic record (send time, position, force) and
  its operator: reach, press and slide along a wall, retreat.

All sans-IO: nothing here reads a clock or touches a socket.
"""
