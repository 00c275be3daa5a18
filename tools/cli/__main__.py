"""`python -m tools.cli`: btf-host."""
import sys

from tools.cli import main

sys.exit(main())
