"""A clean-room implementation of TDTP version 4, written from docs/PROTOCOL.md alone.

It exists to prove that the specification is complete: tools/cleanroom/run_vectors.py runs every
conformance vector file in tests/vectors/ against it. It does not import (or read) the reference
implementation `tdtp`.
"""

from .wire import PROTOCOL_VERSION

__all__ = ["PROTOCOL_VERSION"]
