"""Compiled CasADi code: C generation, compilation and the on-disk cache shared by every solver in seagul.

Two routes, one cache directory (:func:`codegen_cache_dir`: ``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``,
i.e. :func:`seagul_control.io.cache_dir`):

* :func:`compile_nlp_library` generates C for a built NLP solver's functions (or a tuple of plain Functions),
  compiles it once per distinct source and returns the shared library
  (``<name>_<task fingerprint>_<source hash>.so``); :class:`~seagul_control.transcription.Transcription`
  ``codegen=True`` loads solvers from it. A new process with the same problem only regenerates the source (~0.1 s).
* :func:`jit_solver_options` are nlpsol options for CasADi's own JIT, run through a small compiler wrapper that
  caches each object file under a hash of its source, the compiler and the flags (the MPC's scalar JIT).

Both hash the generated source, the compiler and its flags (and the CasADi version), so a changed model or option
never loads a stale artefact; writes are atomic (temporary file, then rename), so concurrent processes building the
same problem are safe. This module was split out of :mod:`seagul_control.transcription`, which still exports every
name defined here.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import casadi as ca

from seagul_control import io as _io
from seagul_control.io import atomic_write_text

#: Flags of the cached C compilation: ``-O1`` compiles the ~1.5 MB generated source in about half the time of
#: ``-O2`` for the same solve speed (measured on the acrobot, docs/experiments/trajopt.md).
CODEGEN_FLAGS: tuple[str, ...] = ("-O1", "-fPIC", "-shared")


def codegen_cache_dir() -> Path:
    """``$SEAGUL_CACHE_DIR`` or ``~/.cache/seagul/casadi``: every compiled CasADi artefact (libraries, JIT objects)."""
    return _io.cache_dir("casadi")


def find_c_compiler() -> str | None:
    """A C compiler on PATH (``$CC``, gcc, cc, clang) or None."""
    for name in (os.environ.get("CC"), "gcc", "cc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def compile_nlp_library(
    solver: ca.Function | tuple[ca.Function, ...],
    name: str,
    cache_dir: str | os.PathLike[str] | None = None,
    fingerprint: str | None = None,
    flags: tuple[str, ...] | None = None,
) -> Path:
    """Generate C for the NLP functions of ``solver``, compile them once per distinct source, return the library.

    ``solver`` may also be a tuple of plain CasADi Functions (e.g. :class:`~seagul_control.shooting.ShootingSolver`'s
    condensed objective and its derivatives): they are generated into one source, loaded with ``ca.external``.

    ``flags``: compiler flags (default :data:`CODEGEN_FLAGS`; must make a shared library).

    The cache key is a hash of the generated source, the compiler and its flags (and the CasADi version, which shapes
    the generated code), so a changed model or option never loads a stale library; ``fingerprint`` (the task's
    :meth:`~seagul_envs.tasks.base.Task.fingerprint`, given by :class:`Transcription`) is part of the file name too,
    ``<name>_<fingerprint>_<hash>.so``, so the libraries of two tasks that differ in any parameter have different
    names. Writes are atomic (temporary file then rename), so concurrent processes building the same problem are
    safe.

    A library named ``<name>_<hash>.so`` (built without a fingerprint) was compiled from the very same source when
    its hash matches: it is hard-linked under the fingerprinted name instead of compiled again.

    Raises:
        RuntimeError: no C compiler, or the compilation failed.
        ValueError: ``fingerprint`` is not a short run of letters and digits.
    """
    if fingerprint is not None and not (fingerprint.isalnum() and fingerprint.isascii() and len(fingerprint) <= 32):
        raise ValueError(f"fingerprint must be at most 32 ASCII letters and digits, got {fingerprint!r}")
    cc = find_c_compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (set $CC or install gcc)")
    flags = CODEGEN_FLAGS if flags is None else tuple(flags)
    cache = codegen_cache_dir() if cache_dir is None else Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="seagul_codegen_", dir=cache) as tmp:
        # CasADi writes the generated file into the working directory and wants a bare C identifier as its name.
        cwd = os.getcwd()
        try:
            os.chdir(tmp)
            if isinstance(solver, tuple):
                gen = ca.CodeGenerator(f"{name}.c")
                for fn in solver:
                    gen.add(fn)
                gen.generate()
            else:
                solver.generate_dependencies(f"{name}.c")
        finally:
            os.chdir(cwd)
        src = Path(tmp) / f"{name}.c"
        digest = hashlib.sha256()
        for part in (ca.__version__, cc, *flags):  # type: ignore[attr-defined]  # missing from casadi.pyi
            digest.update(part.encode() + b"\0")
        digest.update(src.read_bytes())
        source_hash = digest.hexdigest()[:20]
        lib = cache / (f"{name}_{fingerprint}_{source_hash}.so" if fingerprint else f"{name}_{source_hash}.so")
        if lib.is_file():
            return lib
        out = Path(tmp) / f"{name}.so"
        legacy = cache / f"{name}_{source_hash}.so"
        if legacy != lib and legacy.is_file():
            try:
                os.link(legacy, out)
                os.replace(out, lib)
                return lib
            except OSError:  # no hard links on this filesystem: compile
                out.unlink(missing_ok=True)
        proc = subprocess.run([cc, *flags, str(src), "-o", str(out), "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"compiling {src.name} failed: {proc.stderr[-2000:]}")
        os.replace(out, lib)
    return lib


# ----------------------------------------------------------------------------------------------- MPC JIT
# The compiler wrapper CasADi's JIT runs (a standalone script: it runs in the compiler's process, outside seagul, so
# it carries its own atomic copy). Its text is the cache's content check: keep it unchanged unless it must change.
_CC_WRAPPER = '''"""seagul: compile a CasADi JIT source once, then copy the cached object (written by mpc.py)."""
import hashlib, os, shutil, subprocess, sys, tempfile
cache, cc, args = sys.argv[1], sys.argv[2], sys.argv[3:]
src = next((a for a in args if a.endswith(".c")), None)
out = args[args.index("-o") + 1] if "-o" in args else None
if src is None or out is None:
    sys.exit(subprocess.call([cc, *args]))
digest = hashlib.sha256()
digest.update(cc.encode() + b"\\0")
for a in args:
    if a not in (src, out):
        digest.update(a.encode() + b"\\0")
with open(src, "rb") as f:
    digest.update(f.read())
cached = os.path.join(cache, digest.hexdigest() + ".o")
if os.path.isfile(cached):
    shutil.copyfile(cached, out)
    sys.exit(0)
code = subprocess.call([cc, *args])
if code == 0:
    fd, tmp = tempfile.mkstemp(dir=cache, suffix=".tmp")
    os.close(fd)
    shutil.copyfile(out, tmp)
    os.replace(tmp, cached)
sys.exit(code)
'''


def jit_solver_options(cache_dir: Path | None = None, flags: tuple[str, ...] = ("-O1",)) -> dict[str, Any] | None:
    """nlpsol options that JIT-compile the NLP functions through the caching compiler wrapper (None: no compiler).

    The objects are cached in ``cache_dir`` (default :func:`codegen_cache_dir`, shared with
    :func:`compile_nlp_library`) under a hash of the generated source, the compiler and the flags.
    ``-O1`` is the trade-off measured for the acrobot MPC: ``-O0`` code ran 4x slower, ``-O2``/``-O3`` compile
    far longer for no measurable gain on these expression graphs.
    """
    cc = find_c_compiler()
    if cc is None:
        return None
    cache_dir = codegen_cache_dir() if cache_dir is None else Path(cache_dir)
    compiler = cc
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        script = cache_dir / "seagul_cc.py"
        if not script.is_file() or script.read_text() != _CC_WRAPPER:
            atomic_write_text(script, _CC_WRAPPER)
        # CasADi splits the compiler command on whitespace: only use the wrapper when no path contains a space.
        parts = (sys.executable, str(script), str(cache_dir), cc)
        if not any(" " in p for p in parts):
            compiler = " ".join(parts)
    except OSError as exc:
        warnings.warn(f"seagul MPC: JIT cache directory {cache_dir} unusable ({exc}); compiling uncached", stacklevel=2)
    return {
        "jit": True,
        "compiler": "shell",
        "jit_name": "seagul_mpc",
        # A fixed name keeps the generated source identical between runs (the cache key); builds happen in a
        # private directory (the MPC's per-process JIT directory), so equal file names never collide.
        "jit_temp_suffix": False,
        "jit_options": {"compiler": compiler, "flags": list(flags), "verbose": False},
    }


__all__ = ["CODEGEN_FLAGS", "codegen_cache_dir", "compile_nlp_library", "find_c_compiler", "jit_solver_options"]
