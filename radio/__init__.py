"""Packets, framing, authentication and the link protocol, written sans-I/O."""


class FrameError(ValueError):
    """Untrusted bytes that are not a valid frame or packet; the message says why."""
