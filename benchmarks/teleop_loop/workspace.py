"""The task's geometry, shared by both sides (no MuJoCo needed to read it): metres, in the arm's frame.

The wall's face is the plane ``x = WALL_X``; ``arm.xml`` places the wall there, and the fingertip
sphere of radius ``TIP_RADIUS`` touches it when its centre reaches ``CONTACT_X``.
"""

WALL_X = 0.45
TIP_RADIUS = 0.01
CONTACT_X = WALL_X - TIP_RADIUS
REST = (0.35, 0.0)
"""Where the operator's reference starts and returns to between reaches, and where the arm starts."""
TICK = 0.001
"""The control period (s): one position command and one force sample each way per tick (1 kHz)."""
