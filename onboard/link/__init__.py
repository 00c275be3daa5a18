"""The robot's side of the link: the persistent outbox, the packet bodies it sends, the
STATUS it reports, and the transport seam the runtime talks through.
"""
