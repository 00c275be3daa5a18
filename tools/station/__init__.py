"""The station: the one process that owns the radio. It receives and stores (`receiver`),
serves command clients over a local socket (`control`, `command_route`), publishes what it
sees (`bus`, `snapshot`, `log`) and is started by `start`.
"""
