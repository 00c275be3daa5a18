"""The demo on fakes: the end-to-end run (`end_to_end`), the operator's page on a fake robot
(`station_demo`) and the pseudo-terminal cable they run over (`pty_cable`).
"""
