"""Atomic writes of a run folder's files: a complete file or none (write a temporary file beside the target,
give it the usual mode under the umask, then ``os.replace``). A process killed mid-write leaves only a
``.NAME.*.tmp`` file (etb_gym.io.write_atomic), which :func:`remove_temporaries` deletes when the run is resumed."""
from __future__ import annotations

import io
import json
import pickle
from pathlib import Path

from etb_gym.io import is_temporary, write_atomic

TMP_SUFFIX = ".tmp"


def atomic_bytes(path: Path, data: bytes) -> None:
    write_atomic(Path(path), data)


def atomic_json(path: Path, obj) -> None:
    atomic_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def save_model(model, path: Path) -> None:
    buf = io.BytesIO()
    model.save(buf)
    atomic_bytes(path, buf.getvalue())


def save_with(save_fn, path: Path) -> None:
    """Run an SB3 ``save_*(file)`` into a temporary file, then move it into place."""
    write_atomic(Path(path), save_fn)


def dump_pickle(obj, path: Path) -> None:
    save_with(lambda fh: pickle.dump(obj, fh), path)


def remove_temporaries(folder: Path) -> list[Path]:
    """Delete the temporary files that an interrupted atomic write left in ``folder`` (not recursive)."""
    gone = []
    for p in Path(folder).glob("*" + TMP_SUFFIX):
        if p.is_file() and ("." in p.name[:-len(TMP_SUFFIX)] or is_temporary(p)):
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone
