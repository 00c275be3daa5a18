"""The pre-shared link key: 32 random bytes, hex in a file only its owner can read."""
from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

KEY_LEN = 32


class KeyFileError(ValueError):
    """No usable key: the message says what is wrong (never the key itself)."""


def load_key(path: str | os.PathLike[str]) -> bytes:
    """The 32-byte key in `path`; KeyFileError if missing, malformed or readable by others."""
    p = Path(path)
    hint = f"make one with 'btf-host keygen --out {p}'"
    # a damaged key: the other end's copy is the one the link speaks with
    damaged = (f"copy the key from the other end of the link again, or make both ends a new one "
               f"('btf-host keygen --out {p} --force')")
    try:
        st = p.stat()
    except FileNotFoundError:
        raise KeyFileError(f"no key file at {p}: no key, no link ({hint})") from None
    except OSError as exc:
        raise KeyFileError(f"cannot read key file {p}: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError(f"key file {p} is not a regular file")
    if st.st_mode & 0o077:
        raise KeyFileError(f"key file {p} has mode {stat.S_IMODE(st.st_mode):04o}: others may "
                           f"read it; run 'chmod 600 {p}'")
    try:
        text = p.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        raise KeyFileError(f"key file {p} is not readable hex text; {damaged}") from None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise KeyFileError(f"key file {p} does not hold hex digits; {damaged}") from None
    if len(key) != KEY_LEN:
        raise KeyFileError(f"key file {p} holds {len(key)} bytes, expected {KEY_LEN}; {damaged}")
    return key


def write_key(path: str | os.PathLike[str], force: bool = False) -> Path:
    """Write a fresh random key to `path` with mode 0600; FileExistsError unless `force`."""
    p = Path(path)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if force else os.O_EXCL)
    fd = os.open(p, flags, 0o600)
    try:
        os.fchmod(fd, 0o600)  # also when overwriting a file that had looser bits
        os.write(fd, (secrets.token_hex(KEY_LEN) + "\n").encode("ascii"))
        os.fsync(fd)
    finally:
        os.close(fd)
    return p


def counters_beside(key_path: str | os.PathLike[str]) -> Path:
    """Where the host keeps the link counters of the key at `key_path` (`listen` and `cmd`
    speak as one host, so they share them): `<key>.counters.json`."""
    p = Path(key_path)
    return p.with_name(p.name + ".counters.json")


def git_work_tree(path: str | os.PathLike[str]) -> Path | None:
    """The git work tree that contains `path`, if any (a key there risks being committed)."""
    p = Path(path).resolve().parent
    for d in (p, *p.parents):
        if (d / ".git").exists():
            return d
    return None
