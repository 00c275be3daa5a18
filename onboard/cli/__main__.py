"""`python -m onboard.cli`: btf-robot."""
import sys

from onboard.cli import main

sys.exit(main())
