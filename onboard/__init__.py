"""The lean robot runtime: the main loop, its configuration, commands and failsafe.

`onboard.capture` measures one pose, `onboard.sweep` plans and runs sweeps, `onboard.link` is
the robot's side of the radio (outbox, packet bodies, STATUS), and `onboard.cli` is `btf-robot`.
The fitter itself is shared with the host (`btf.fit`). Imports numpy, msgpack and the standard
library only.
"""
