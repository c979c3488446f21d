"""Files on disk for every seagul package: the one atomic writer, JSON files written through it, and the one cache
directory.

Only the standard library is imported here (no torch, no CasADi), so ``seagul_envs``, ``seagul_control`` and
``seagul_learn`` may all use it, and so may user code that writes files next to the library's (result JSON,
checkpoints). ``seagul_control._io``, the module's former private name, is the same module object.

Usage::

    from seagul_control.io import atomic_write_json, cache_dir, read_json

    atomic_write_json(out / "summary.json", {"success_rate": 0.98}, indent=2)
    summary = read_json(out / "summary.json")
    solvers = cache_dir("casadi")  # where compiled CasADi code is kept

**Atomic writes.** :func:`atomic_write_bytes` writes to a hidden ``.tmp-*`` file in the target's own directory
(same filesystem, so the rename is atomic), flushes and fsyncs it, renames it over the target (``os.replace``) and
fsyncs the directory. A reader sees the old file or the complete new one, never a torn one, whenever the writer is
killed; a write that fails (full disk, exception while writing) removes its temp file and leaves the old file as
it was. Killed writers leave at worst a stray ``.tmp-*`` file, which the dataset readers ignore and clean.

**JSON.** :func:`atomic_write_json` is ``json.dumps`` through the atomic writer, with the layout as arguments (the
committed result files each keep their own: the same arguments give the same bytes), and :func:`read_json` reads a
file back, naming the file when it is not JSON (a file cut short by a writer that did not use this module).

**Cache directory.** :func:`cache_dir` is the only place that reads ``$SEAGUL_CACHE_DIR``: compiled CasADi code
(the transcription's code-generated libraries and the MPC's JIT objects, ``cache_dir("casadi")``) and solved
validation sets (``cache_dir()``) are cached there.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

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


def atomic_write_json(
    path: str | os.PathLike[str],
    data: Any,
    *,
    indent: int | None = None,
    sort_keys: bool = False,
    allow_nan: bool = True,
    newline: bool = False,
) -> None:
    """Write ``json.dumps(data, indent=indent, sort_keys=sort_keys, allow_nan=allow_nan)`` to ``path`` atomically
    (see :func:`atomic_write_bytes`), with a final ``"\\n"`` when ``newline``.

    ``allow_nan`` is True by default, as in ``json.dumps``: NaN and infinities (an undefined median, an episode
    without solves) are written as ``NaN``/``Infinity``, which Python's ``json`` reads back; pass False for files that
    other JSON readers must parse (it then raises ``ValueError`` before anything is written).
    """
    text = json.dumps(data, indent=indent, sort_keys=sort_keys, allow_nan=allow_nan)
    atomic_write_text(path, text + "\n" if newline else text)


def read_json(path: str | os.PathLike[str]) -> Any:
    """The JSON value stored in ``path`` (``NaN``/``Infinity`` included).

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not JSON; the message names the file and the position.
    """
    text = Path(path).read_text(encoding="utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not a JSON file: {e}") from e


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


__all__ = [
    "CACHE_ENV",
    "TEMP_PREFIX",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "cache_dir",
    "read_json",
]
