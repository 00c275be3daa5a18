"""`python -m radio.packets`: the packet schema's document (docs/packets.md)."""
from radio.packets.doc import document

print(document(), end="")
