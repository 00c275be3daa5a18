"""`btfsim://?port=URL&loss=...`: the seeded lossy radio in front of another port (see
`radio.channel_port`)."""
from radio.channel_port import ChannelPort as Serial  # noqa: F401  (pyserial looks for `Serial`)
