"""Emulators: devices simulated at the wire (pty bytes, smbus2 calls, OpenCV sources),
so the real drivers' code runs in tests without hardware."""
