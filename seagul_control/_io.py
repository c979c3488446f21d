"""Files on disk for every seagul package: the one atomic writer and the one cache directory.

Only the standard library is imported here (no torch, no CasADi), so ``seagul_envs``, ``seagul_control`` and
``seagul_learn`` may all use it.

**Atomic writes.** :func:`atomic_write_bytes` writes to a hidden ``.tmp-*`` file in the target's own directory
(same filesystem, so the rename is atomic), flushes and fsyncs it, renames it over the target (``os.replace``) and
fsyncs the directory. A reader sees the old file or the complete new one, never a torn one, whenever the writer is
killed; a write that fails (full disk, exception while writing) removes its temp file and leaves the old file as
it was. Killed writers leave at worst a stray ``.tmp-*`` file, which the dataset readers ignore and clean.

**Cache directory.** :func:`cache_dir` is the only place that reads ``$SEAGUL_CACHE_DIR``: compiled CasADi code
(the transcription's code-generated libraries and the MPC's JIT objects, ``cache_dir("casadi")``) and solved
validation sets (``cache_dir()``) are cached there.
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

#: Environment variable naming the cache directory (see :func:`cache_dir`).
CACHE_ENV = "SEAGUL_CACHE_DIR"

#: Prefix of the temporary files of :func:`atomic_write_bytes` (readers of a directory skip such names).
TEMP_PREFIX = ".tmp-"


def cache_dir(subdir: str = "") -> Path:
    """``$SEAGUL_CACHE_DIR`` when it is set (used as is, for every cache), else ``~/.cache/seagul/<subdir>``.

    Args:
        subdir: sub-directory of the default location for this kind of cache: ``"casadi"`` for compiled CasADi
            code, ``""`` for data (validation sets). It does not apply when ``$SEAGUL_CACHE_DIR`` is set: the user's
            directory then holds every cache (their file names never collide).
    """
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env)
    root = Path.home() / ".cache" / "seagul"
    return root / subdir if subdir else root


def _current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: a ``.tmp-*`` file beside it, fsync, rename, fsync the directory.

    A reader sees the old file or the complete new one, never a torn one, whenever the writer is killed; on an error
    the temporary file is removed, the old file (if any) is left untouched and the error propagates. Parent
    directories are created. The file gets the permissions ``open`` would give it (0666 less the umask; an existing
    file keeps its own), not the owner-only mode of the temporary file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except OSError:
        mode = 0o666 & ~_UMASK
    fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, text.encode(encoding))


def _fsync_dir(path: Path) -> None:
    """fsync a directory so that a rename in it survives a power loss (best effort)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # some filesystems/platforms cannot open directories
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


__all__ = ["CACHE_ENV", "TEMP_PREFIX", "atomic_write_bytes", "atomic_write_text", "cache_dir"]
