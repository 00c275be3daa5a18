"""What several test modules share: the repository's root, rigs, browsers, small disks, robots."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
