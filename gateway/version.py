"""What `invt-gateway --version` says: the release, and the commit when run from a git checkout.

A build from a checkout between releases says which commit it is ("0.2.0 (commit 1a2b3c4)"), so
a report from the field can be matched to the code; an installed release (a wheel, the Docker
image) has no checkout beside it and says the release alone.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from gateway import __version__


def checkout_commit(package: Path = Path(__file__).parent) -> str | None:
    """The short commit of the git checkout this package runs from, or None (not a checkout,
    no git, or git says nothing within a second)."""
    root = package.parent
    if not (root / ".git").exists():
        return None
    try:
        done = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=1,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = done.stdout.strip()
    return commit if done.returncode == 0 and commit else None


def describe_version() -> str:
    commit = checkout_commit()
    return __version__ if commit is None else f"{__version__} (commit {commit})"
