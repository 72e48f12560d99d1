"""Whether the console's editor may write the configuration file, and if not, why, said so an
installer knows what to change.

The editor writes a new file beside the configuration and renames it over the old one (never a
half-written file), so it needs the directory writable, not only the file. What stops it, in the
order it is looked at:

- a read-only mount: Docker's `-v DIR:/etc/invt-gateway:ro`, a systemd unit that leaves the
  directory under `ProtectSystem=` (root is refused there too);
- a file mounted on its own (`docker run -v FILE:/etc/invt-gateway/config.yaml`): a new file
  can't be renamed over a mount point (the kernel answers EBUSY);
- a file marked read-only (no write bit at all, `chmod a-w`): someone said so on purpose, so it
  is refused for root too, where the kernel would let root replace it;
- a file or a directory the gateway's user may not write (root's, when the service runs as
  `invt-gateway`).

The same words serve the page (shown when the file is loaded, Apply disabled) and the refusal of
an apply; a write that fails anyway (the file changed meanwhile) is said with its errno.
"""

from __future__ import annotations

import errno
import os
import pwd
import re
import stat
from pathlib import Path
from typing import Final

MOUNTS: Final = Path("/proc/self/mountinfo")
_OCTAL: Final = re.compile(rb"\\([0-7]{3})")


def refusal(path: str) -> str | None:
    """Why the console can't write `path` (a sentence naming it), or None when it can."""
    target = Path(path)
    why = _why(target)
    return None if why is None else f"{path} cannot be changed from the console: {why}"


def write_failed(path: str, error: OSError) -> str:
    """A write that failed after `refusal` found nothing: what the kernel said, in these words."""
    why = _why(Path(path))
    if why is None and error.errno == errno.EBUSY:
        why = _MOUNTED_ALONE
    if why is None:
        why = f"writing it failed: {error.strerror or error}"
    return f"{path} cannot be changed from the console: {why}"


_MOUNTED_ALONE: Final = (
    "the file is mounted on its own (as `docker run -v FILE:FILE` mounts it), and a new file "
    "can't be renamed over a mount point: mount its directory instead"
)


def _why(target: Path) -> str | None:
    directory = target.parent
    try:
        on_file = target.stat()
        in_directory = directory.stat()
    except OSError as exc:
        return f"it can't be looked at: {exc.strerror or exc}"
    if _read_only_mount(target):
        return (
            "it is on a read-only mount (a Docker volume given with `:ro`, or a directory "
            "systemd's ProtectSystem= keeps read-only): nothing can write there, root neither"
        )
    if _mount_point(target):
        return _MOUNTED_ALONE
    if on_file.st_mode & 0o222 == 0:
        return (
            f"the file is marked read-only (mode {_mode(on_file)}), so the console leaves it "
            "as it is; make it writable (chmod u+w) to edit it here"
        )
    if not os.access(target, os.W_OK):
        return (
            f"the gateway runs as {_user()}, which may not write it ({_owner(on_file)}'s, "
            f"mode {_mode(on_file)}); give it to that user (chown) to edit it here"
        )
    if not os.access(directory, os.W_OK | os.X_OK):
        return (
            f"the gateway runs as {_user()}, which may not write in its directory {directory} "
            f"({_owner(in_directory)}'s, mode {_mode(in_directory)}), where the console writes "
            "the new file before renaming it over the old; give the directory to that user"
        )
    return None


def _read_only_mount(target: Path) -> bool:
    return any(os.statvfs(place).f_flag & os.ST_RDONLY for place in (target, target.parent))


def _mount_point(target: Path) -> bool:
    """Whether `target` itself is mounted (a bind of one file), from the kernel's mount table."""
    try:
        table = MOUNTS.read_bytes()
    except OSError:  # no /proc: the rename says EBUSY, `write_failed` words it the same
        return False
    where = os.fsencode(os.path.realpath(target))
    # Field 5 is the mount point, a space and the like written as octal escapes (`\040`).
    points = (fields[4] for fields in map(bytes.split, table.splitlines()) if len(fields) > 4)
    return any(_OCTAL.sub(lambda code: bytes([int(code[1], 8)]), p) == where for p in points)


def _mode(found: os.stat_result) -> str:
    return f"{stat.S_IMODE(found.st_mode):04o}"


def _owner(found: os.stat_result) -> str:
    return _name(found.st_uid)


def _user() -> str:
    """`invt-gateway (uid 998)`; a uid no account names (a container's 10001) alone."""
    uid = os.geteuid()
    name = _name(uid)
    return name if name.startswith("uid ") else f"{name} (uid {uid})"


def _name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:  # a user only a uid names (a container's 10001, a test's)
        return f"uid {uid}"
