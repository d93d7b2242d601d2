"""The dashboard's clip cache: rendered MP4s in a directory the dashboard owns, read back only as files it wrote.

A clip is named by what decides its pixels (the run, its task definition and best CMRT, the frame rate), so anyone
holding a store knows its name. The cache was once a folder beside the store, and a store shipped together with
that folder could hold ``run1-<key>.mp4 -> /etc/passwd``: the dashboard served /etc/passwd as ``video/mp4``. Now:

* the cache is this user's (``$XDG_CACHE_HOME/cmrt/dashboard-clips``, else ``~/.cache/cmrt/dashboard-clips``, or
  the directory the dashboard is configured with): created with mode 0700 and used only while it is a directory
  (not a symlink) owned by this user that nobody else may write;
* a clip is opened with ``O_NOFOLLOW`` (a symlink is refused, not followed) and ``O_NONBLOCK`` (a FIFO does not
  block), and served only if what was opened is a regular file owned by this user, with one link, that nobody
  else may write; its bytes are read from that descriptor, never from the path again;
* a clip is rendered into a new temporary file of the cache and renamed onto its name: a rename replaces the
  directory entry, never a file a symlink points to. Anything else found under a clip's name is rendered over.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

from cmrt.errors import CmrtError, DiskFull

MAX_CLIP_BYTES = 512 * 1024 * 1024  # a cached clip larger than this is not one the dashboard rendered


class Unavailable(CmrtError):
    """A clip that cannot be rendered or kept here (no OpenGL backend, a cache that is not this user's): a 503, not a
    damaged store."""


def default_dir() -> Path:
    """``$XDG_CACHE_HOME/cmrt/dashboard-clips``, else ``~/.cache/cmrt/dashboard-clips``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "cmrt" / "dashboard-clips"


def owned_dir(path: Path) -> Path:
    """``path`` as a cache directory this user owns: created (mode 0700) if missing; CmrtError if it is a symlink,
    not a directory, another user's, or writable by others."""
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        st = os.lstat(path)
    except OSError as exc:
        raise Unavailable(f"cannot make the clip cache {path}: {exc.strerror or exc}") from None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.geteuid() or st.st_mode & 0o022:
        raise Unavailable(f"the clip cache {path} is not a directory of this user's that only it may write "
                        "(a symlink, another user's, or open to others): not used")
    return path


def read_owned(path: Path) -> bytes | None:
    """The bytes of ``path`` if it is a clip this user's dashboard wrote (a regular file owned by this user, one
    link, writable by nobody else, not reached through a symlink); None otherwise (missing, or anything else)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:  # missing, a symlink (ELOOP), a socket, no permission
        return None
    try:
        st = os.fstat(fd)
        if (not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or st.st_nlink != 1 or st.st_mode & 0o022
                or st.st_size > MAX_CLIP_BYTES):
            return None
        with os.fdopen(os.dup(fd), "rb") as fh:
            return fh.read(MAX_CLIP_BYTES + 1)
    finally:
        os.close(fd)


def cached(directory: Path, name: str, make: Callable[[Path], None]) -> bytes:
    """The clip ``name`` of cache ``directory``: read back if this dashboard wrote it, else made by ``make(tmp)``
    into a new file of the cache and renamed onto ``name``. :class:`Unavailable` if the cache is not one this user
    owns or the clip cannot be made or stored; DiskFull on a full disk."""
    directory = owned_dir(directory)
    path = directory / name
    if (data := read_owned(path)) is not None:
        return data
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".rendering-", suffix=path.suffix)
        os.close(fd)
    except OSError as exc:
        raise _store_error(directory, exc) from None
    try:
        make(Path(tmp))
        os.replace(tmp, path)
    except OSError as exc:
        raise _store_error(directory, exc) from None
    except CmrtError as exc:  # the renderer's own refusal: no OpenGL backend here
        raise Unavailable(str(exc)) from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
    if (data := read_owned(path)) is None:
        raise Unavailable(f"the clip {path} changed under the dashboard: not served")
    return data


def _store_error(directory: Path, exc: OSError) -> Exception:
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return DiskFull(f"cannot cache a clip in {directory}: disk full (free some space and ask again)")
    return Unavailable(f"cannot cache a clip in {directory}: {exc.strerror or exc}")
