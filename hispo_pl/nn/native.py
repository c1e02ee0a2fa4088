"""The fused LayerNorm → GELU → dropout kernels of ``fused.c`` and its random bytes for
dropout, built with the machine's C compiler on first use and called through ctypes.

Torch runs LayerNorm, GELU, the mask's product and their backwards as separate kernels, each a
pass over a ``[batch, hidden]`` activation, plus one more for a linear layer's bias gradient;
``fused.c`` does each direction in one pass per row, which matters most in the backward, where
every pass reads activations saved long before. Same maths as the aten kernels (tested).

The library is compiled once per machine (``-march=native``, the vector ``erff``/``expf`` of
glibc's libmvec) into ``$HISPO_PL_CACHE`` (default ``~/.cache/hispo-pl``), keyed by the
source, the flags, the compiler and the CPU, in a directory no other user can write; it is
loaded only while its bytes match the digest written beside it. Without a C compiler, off
glibc, or with ``HISPO_PL_NATIVE=0``, :func:`library` returns ``None`` and
:mod:`~hispo_pl.nn.fast` keeps the aten kernels.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import logging
import os
import platform
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path

import torch
from torch import Tensor

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("fused.c")
FLAGS = ("-O3", "-march=native", "-fno-math-errno", "-fopenmp-simd", "-shared", "-fPIC")
LIBS = ("-lmvec", "-lm")
_P, _LONG, _INT, _FLOAT = ctypes.c_void_p, ctypes.c_long, ctypes.c_int, ctypes.c_float
_SIGNATURES = {
    "ln_gelu_drop_forward": [_LONG, _LONG, *[_P] * 5, _INT, _FLOAT, _FLOAT, *[_P] * 3],
    "ln_gelu_drop_backward": [_LONG, _LONG, _P, _P, _INT, _FLOAT, *[_P] * 12],
    "random_bytes": [_LONG, ctypes.c_uint64, _P],
}
_state: dict[str, ctypes.CDLL | None] = {}


def cache_dir() -> Path:
    """Where built libraries go: ``$HISPO_PL_CACHE``, else ``$XDG_CACHE_HOME/hispo-pl``, else
    ``~/.cache/hispo-pl`` (the temporary directory without a home)."""
    if os.environ.get("HISPO_PL_CACHE"):
        return Path(os.environ["HISPO_PL_CACHE"])
    try:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    except RuntimeError:  # no home directory to be found
        return Path(tempfile.gettempdir()) / f"hispo-pl-{os.getuid()}"
    return Path(base) / "hispo-pl"


def _cpu_key() -> str:
    """The CPU's model and feature flags (``-march=native`` builds for exactly them)."""
    try:
        info = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor()
    wanted = ("model name", "flags", "Features", "CPU part")
    return "\n".join(sorted({line for line in info if line.split(":")[0].strip() in wanted}))


COMPILE_TIMEOUT_S = 30  # the build takes about a second; a hung compiler costs no more


def build(compiler: str | None = None, directory: Path | None = None) -> Path | None:
    """Compile ``fused.c`` unless this machine's library is there; its path, or ``None`` when
    there is no compiler or the build fails (the reason is logged). Without ``directory``, in
    :func:`cache_dir`, or in the temporary directory where that is not writable or not ours.

    Only a directory this user owns and no one else can write is used (created ``0700``), and a
    library found there is used only if its bytes match the digest written when it was built;
    otherwise it is rebuilt. So no other local user can plant the code this process loads."""
    compiler = compiler or os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        log.info("no C compiler found: the fused kernels are off")
        return None
    try:
        version = subprocess.run(
            [compiler, "--version"], capture_output=True, text=True, timeout=10
        ).stdout
    except (OSError, subprocess.SubprocessError) as err:
        log.info("C compiler %s unusable (%s): the fused kernels are off", compiler, err)
        return None
    key = hashlib.sha256(
        "\0".join([SOURCE.read_text(), *FLAGS, *LIBS, version, _cpu_key()]).encode()
    ).hexdigest()[:16]
    fallback = Path(tempfile.gettempdir()) / f"hispo-pl-{os.getuid()}"
    for where in [Path(directory)] if directory is not None else [cache_dir(), fallback]:
        path = where / f"fused-{key}.so"
        try:
            why = _private_dir(where)
            if why is not None:
                log.warning("not using %s for the fused kernels: %s", where, why)
                continue
            if _intact(path) or _compile(compiler, path):
                return path
        except subprocess.TimeoutExpired:
            log.warning("the C compiler %s hung: the fused kernels are off", compiler)
            return None
        except (OSError, subprocess.SubprocessError) as err:
            log.info("building %s in %s failed (%s)", SOURCE, where, err)
        else:
            return None  # the compiler refused the source: another directory will not help
    log.info("no private writable directory for the fused kernels: they are off")
    return None


def untrusted(path: Path) -> str | None:
    """Why code under ``path`` could have been written by someone else, or None: it must not
    be a link, must belong to this user, and no group or other user may write it."""
    info = path.lstat()
    if stat.S_ISLNK(info.st_mode):
        return "it is a symbolic link"
    if info.st_uid != os.getuid():
        return f"it belongs to user id {info.st_uid}"
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"others can write it (mode {stat.S_IMODE(info.st_mode):o})"
    return None


def _private_dir(where: Path) -> str | None:
    """Make ``where`` (mode ``0700``) if missing; why it cannot hold our library, or None."""
    if not os.path.lexists(where):
        where.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileExistsError):  # a concurrent build made it: check it
            os.mkdir(where, 0o700)
    if not where.is_dir():
        raise NotADirectoryError(f"{where} is not a directory")
    return untrusted(where)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _intact(path: Path) -> bool:
    """Whether ``path`` is a library this user built: its own file, and its bytes those of the
    digest beside it (a truncated or corrupt library would crash the process when loaded)."""
    stamp = path.with_suffix(".sha256")
    if not (path.is_file() and stamp.is_file()) or untrusted(path) or untrusted(stamp):
        return False
    return stamp.read_text().strip() == _digest(path)


def _compile(compiler: str, path: Path) -> bool:
    """Build the library at ``path`` with its digest beside it (atomically: a concurrent build
    of it is harmless); whether the compiler succeeded (its errors are logged)."""
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        out = Path(tmp) / path.name
        done = subprocess.run(
            [compiler, *FLAGS, str(SOURCE), "-o", str(out), *LIBS],
            capture_output=True,
            text=True,
            timeout=COMPILE_TIMEOUT_S,
        )
        if done.returncode != 0:
            log.info("building %s failed: the fused kernels are off\n%s", SOURCE, done.stderr)
            return False
        os.chmod(out, 0o755)  # whatever the umask: writable by this user alone
        stamp = Path(tmp) / "digest"
        stamp.write_text(_digest(out))
        os.chmod(stamp, 0o644)
        os.replace(out, path)
        os.replace(stamp, path.with_suffix(".sha256"))
    return True


def library() -> ctypes.CDLL | None:
    """The loaded kernels (built on the first call), or ``None`` where they are off."""
    if "lib" not in _state:
        _state["lib"] = _load()
    return _state["lib"]


def _load() -> ctypes.CDLL | None:
    if os.environ.get("HISPO_PL_NATIVE", "1") == "0" or platform.system() != "Linux":
        return None
    path = build()
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as err:
        log.info("loading %s failed (%s): the fused kernels are off", path, err)
        return None
    for name, argtypes in _SIGNATURES.items():
        getattr(lib, name).argtypes = argtypes
        getattr(lib, name).restype = None
    return lib


def random_bytes(out: Tensor) -> Tensor:
    """Fill ``out`` (uint8, contiguous, on the CPU) with uniform random bytes, seeded by one
    64-bit draw from torch's default generator (``torch.manual_seed`` makes them repeat);
    many times cheaper than ``random_`` on CPU."""
    seed = torch.empty((), dtype=torch.int64).random_(-(2**63), None).item() % 2**64
    library().random_bytes(out.numel(), seed, _ptr(out))
    return out


def usable(*tensors: Tensor | None) -> bool:
    """Whether the kernels are built and take these tensors (on the CPU, contiguous, float32 or,
    for dropout bytes, uint8; ``None`` stands for an absent dropout or residual) in a 1-thread
    process (the kernels are single-threaded; with more threads aten's kernels share the
    work)."""
    return (
        torch.get_num_threads() == 1
        and library() is not None
        and all(
            t is None
            or (
                t.dtype in (torch.float32, torch.uint8)
                and t.device.type == "cpu"
                and t.is_contiguous()
            )
            for t in tensors
        )
    )


def _ptr(t: Tensor | None) -> int | None:
    return None if t is None else t.data_ptr()


Dropout = tuple[Tensor, int, float]
"""A layer's dropout: uint8 bytes of the activation's shape, threshold, scale (a unit is kept,
times the scale, iff its byte is ≥ the threshold)."""


def _dropout_args(dropout: Dropout | None) -> tuple[int | None, int, float]:
    if dropout is None:
        return None, 0, 1.0
    keep, threshold, scale = dropout
    return _ptr(keep), threshold, scale


def ln_gelu_drop_forward(
    a: Tensor, g: Tensor, e: Tensor, eps: float, dropout: Dropout | None, res: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """``y = GELU(LayerNorm(a; g, e) [+ res]) [* dropout]`` for a 2-D ``a``; returns ``y`` and
    the rows' mean and reciprocal standard deviation."""
    rows, cols = a.shape
    y, mu, rstd = torch.empty_like(a), a.new_empty(rows), a.new_empty(rows)
    library().ln_gelu_drop_forward(
        rows, cols, _ptr(a), _ptr(g), _ptr(e), _ptr(res), *_dropout_args(dropout), eps,
        _ptr(y), _ptr(mu), _ptr(rstd),
    )  # fmt: skip
    return y, mu, rstd


def ln_gelu_drop_backward(
    dy: Tensor,
    saved: tuple[Tensor, Tensor, Tensor],
    g: Tensor,
    e: Tensor,
    dropout: Dropout | None,
    res: Tensor | None = None,
    want_dpre: bool = False,
) -> tuple[Tensor | None, Tensor, Tensor, Tensor, Tensor]:
    """Gradients of :func:`ln_gelu_drop_forward` given ``dy`` and ``saved`` (its input ``a``
    and the rows' mean and reciprocal std): ``dpre``, the gradient of the GELU's input (when
    wanted, else ``None``), ``da``, ``dg``, ``de``, and ``db``, the column sums of ``da`` (the
    bias gradient of the linear layer that made ``a``)."""
    a, mu, rstd = saved
    rows, cols = a.shape
    dpre = torch.empty_like(a) if want_dpre else None
    da, sums, scratch = torch.empty_like(a), a.new_empty(3, cols), a.new_empty(cols)
    library().ln_gelu_drop_backward(
        rows, cols, _ptr(dy), *_dropout_args(dropout), _ptr(a), _ptr(mu), _ptr(rstd),
        _ptr(g), _ptr(e), _ptr(res), _ptr(dpre), _ptr(da), _ptr(sums[0]), _ptr(sums[1]),
        _ptr(sums[2]), _ptr(scratch),
    )  # fmt: skip
    dg, de, db = sums.unbind(0)
    return dpre, da, dg, de, db
