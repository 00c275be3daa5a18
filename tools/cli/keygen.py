"""`btf-host keygen`: make the pre-shared link key file."""
from __future__ import annotations

import argparse
import sys

from radio.auth import write_fresh
from radio.keys import counters_beside, git_work_tree, write_key
from tools.cli.options import CliError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="key file to create (keep it outside the repository)")
    p.add_argument("--force", action="store_true", help="overwrite an existing key file")


def run(args: argparse.Namespace) -> int:
    try:
        path = write_key(args.out, force=args.force)
    except FileExistsError:
        raise CliError(f"{args.out} exists; pass --force to replace it (old links stop working)") from None
    except OSError as exc:
        raise CliError(f"cannot write key file {args.out}: {exc.strerror}") from None
    try:  # a new key has used no counter: the host's counters start afresh
        write_fresh(counters_beside(path))
    except OSError as exc:
        raise CliError(f"cannot write {counters_beside(path)}: {exc.strerror}") from None
    tree = git_work_tree(path)
    if tree is not None:
        print(f"warning: {path} is inside the git work tree {tree}; keep keys out of repositories",
              file=sys.stderr)
    print(f"wrote a 32-byte key to {path} (mode 0600) and this host's fresh link counters for it to "
          f"{counters_beside(path)}; copy the key to both ends of the link")
    return 0
