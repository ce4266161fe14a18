"""Atomic writes of a run folder's files: a complete file or none (write a temporary file beside the target,
give it the usual mode under the umask, then ``os.replace``). A process killed mid-write leaves only a
``NAME.*.tmp`` file, which :func:`remove_temporaries` deletes when the run is resumed."""
from __future__ import annotations

import io
import json
import os
import pickle
import tempfile
from pathlib import Path

TMP_SUFFIX = ".tmp"


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def atomic_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=TMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_umask())          # mkstemp creates 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_json(path: Path, obj) -> None:
    atomic_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def save_model(model, path: Path) -> None:
    buf = io.BytesIO()
    model.save(buf)
    atomic_bytes(path, buf.getvalue())


def save_with(save_fn, path: Path) -> None:
    """Run an SB3 ``save_*(file)`` into a temporary file, then move it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=TMP_SUFFIX)
    os.close(fd)
    try:
        with open(tmp, "wb") as fh:
            save_fn(fh)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def dump_pickle(obj, path: Path) -> None:
    save_with(lambda fh: pickle.dump(obj, fh), path)


def remove_temporaries(folder: Path) -> list[Path]:
    """Delete the temporary files that an interrupted atomic write left in ``folder`` (not recursive)."""
    gone = []
    for p in Path(folder).glob("*" + TMP_SUFFIX):
        if p.is_file() and "." in p.name[:-len(TMP_SUFFIX)]:
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone
