"""Files: written so that a killed process never leaves them half written, and known by their first bytes."""

from __future__ import annotations

import glob
import os
import re
import socket
import threading
import time
import tokenize
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


@contextmanager
def replaced(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (same folder, same suffix, so that numpy and netCDF writers
    keep its name; one per process and thread) to write in the block: renamed onto ``path`` when the block
    ends, removed if it raises. A process killed while writing leaves the previous file whole, or
    none: never a cut one that the next run cannot read (a cut history lost its steps, a cut
    emulator stopped every rerun)."""
    path = Path(path)
    _remove_orphans(path)
    # Per process and thread: two writers never share one. Per process only, two threads of one
    # Dask worker (--threads-per-worker 2) writing one file (a plant both grew) wrote into the same
    # temporary file, and the second to finish failed with FileNotFoundError (the first had moved it).
    tmp = path.with_name(f"{_PARTIAL}-{_HOST}-{os.getpid()}-t{threading.get_native_id()}-{path.name}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


_PARTIAL = ".partial"
#: This machine in a temporary file's name: a folder shared with other machines' workers (a
#: distributed run) holds their writers' files too, whose process ids mean nothing here.
_HOST = "".join(c if c.isalnum() else "_" for c in socket.gethostname()) or "host"


#: Seconds since its last change after which a dead writer's temporary file is an orphan.
ORPHAN_AGE_S = 600.0


def _remove_orphans(path: Path) -> None:
    """Remove the temporary files of ``path`` that this machine's processes left when they were
    killed outright (SIGKILL, a worker stopped at once after Ctrl-C: no ``finally`` ran): their
    process no longer exists and they have not changed for :data:`ORPHAN_AGE_S`. Another machine's
    and a live process's are left alone; the age spares a live writer whose process id this one
    cannot see (a container with its own process ids sharing the folder and the host name)."""
    for tmp in path.parent.glob(f"{_PARTIAL}-{_HOST}-*-{glob.escape(path.name)}"):
        # "<pid>-t<thread>", or "<pid>" (written before the thread was in the name)
        writer = re.fullmatch(r"(\d+)(?:-t\d+)?", tmp.name[len(f"{_PARTIAL}-{_HOST}-") : -len(path.name) - 1])
        try:
            old = time.time() - tmp.stat().st_mtime > ORPHAN_AGE_S
        except FileNotFoundError:  # its writer finished meanwhile
            continue
        if old and writer and not _alive(int(writer[1])):
            tmp.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def replace_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) at ``path`` through :func:`replaced`."""
    with replaced(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


#: First bytes of a netCDF file: netCDF-4 (HDF5) and classic netCDF (32-bit, 64-bit offsets, CDF-5).
NETCDF_MAGIC = (b"\x89HDF\r\n\x1a\n", b"CDF\x01", b"CDF\x02", b"CDF\x05")


def is_netcdf(path: str | Path) -> bool:
    """Whether the file at ``path`` starts as a netCDF file does (:data:`NETCDF_MAGIC`)."""
    with open(path, "rb") as f:
        return f.read(8).startswith(NETCDF_MAGIC)


def jsonable(d: Any, strict: bool = False) -> Any:
    """``d`` with numpy arrays and scalars turned into lists and Python numbers (for ``json.dumps``);
    ``strict``: non-finite numbers as ``None`` too (JSON has no Infinity or NaN: strict parsers,
    jq and JavaScript, refuse them)."""
    if isinstance(d, dict):
        return {k: jsonable(v, strict) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [jsonable(v, strict) for v in d]
    if isinstance(d, np.ndarray):
        return jsonable(d.tolist(), strict) if strict else d.tolist()
    if isinstance(d, (np.floating, np.integer, np.bool_)):
        d = d.item()
    if strict and isinstance(d, float) and not np.isfinite(d):
        return None
    return d


#: What ``np.load`` of a damaged or unreadable ``.npz`` or ``.npy`` raises (a cut copy, a full disk, a
#: byte flipped, an empty file): a cache that catches these renders or rebuilds the file instead.
#: ``tokenize.TokenError``: a flipped byte that unbalances an array header's brackets, which numpy
#: re-reads through :mod:`tokenize` (whose error is no ValueError) for headers of format 1 and 2.
UNREADABLE_NPZ = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, tokenize.TokenError)


def load_npz(path: str | Path, **kwargs):
    """``np.load(path, **kwargs)`` of an ``.npz`` archive, for files a cache reads back: a single
    ``.npy`` array under that name (a foreign file: ``np.load`` returns the array itself, and ``with``
    on it stopped with a TypeError traceback) raises ValueError, one of :data:`UNREADABLE_NPZ`."""
    z = np.load(path, **kwargs)
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{path} holds a single array (.npy), not an .npz archive")
    return z


__all__ = ["NETCDF_MAGIC", "UNREADABLE_NPZ", "is_netcdf", "jsonable", "load_npz", "replace_text", "replaced"]
