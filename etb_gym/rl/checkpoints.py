"""The checkpoints of a run folder: write them atomically, find the one to resume from, and refuse a damaged
one with a sentence that names the file and offers the last intact older checkpoint.

``checkpoints/`` holds, per checkpoint ``ckpt_N`` (N = timesteps; ``ckpt_N_interrupted`` on Ctrl-C)::

    ckpt_N.zip                   the model (SB3 zip)
    ckpt_N_replay_buffer.pkl     off-policy algorithms
    ckpt_N_vecnormalize.pkl      with normalize=True
    ckpt_N.json                  the entry: timesteps, files with their size and SHA-256, wall time, best score
    latest.json                  a copy of the newest entry (written last: a checkpoint exists once it names it)

Every file is written whole or not at all (:mod:`etb_gym.rl.files`), so a process killed at any point
(SIGKILL included) leaves the previous checkpoint intact; the sizes and digests catch files damaged later
(a truncated copy, a full disk).
"""
from __future__ import annotations

import hashlib
import json
import re
import zipfile
from pathlib import Path

from .files import atomic_json, save_model, save_with

CHECKPOINT_DIR = "checkpoints"
LATEST = "latest.json"
KEEP_CHECKPOINTS = 2
_NAME = re.compile(r"^ckpt_(\d+)(_interrupted)?$")
_FILE_KEYS = ("model", "replay_buffer", "vecnormalize")


class CheckpointError(ValueError):
    """A checkpoint cannot be used; the message names the file and the way forward."""


def _digest(path: Path) -> dict:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return {"bytes": path.stat().st_size, "sha256": h.hexdigest()}


def _structure_problem(path: Path) -> str | None:
    """For files without a recorded digest (runs written before digests): a zip must pass its CRC test, a
    pickle must end with the STOP opcode."""
    if path.suffix == ".zip":
        try:
            with zipfile.ZipFile(path) as z:
                bad = z.testzip()
        except (zipfile.BadZipFile, OSError, EOFError) as exc:
            return f"is not a readable zip archive ({exc})"
        return None if bad is None else f"is damaged (member {bad} fails its CRC check)"
    with open(path, "rb") as fh:
        fh.seek(0, 2)
        if fh.tell() == 0:
            return "is empty"
        fh.seek(-1, 2)
        if fh.read(1) != b".":
            return "is truncated (the pickle does not end with its STOP opcode)"
    return None


class Checkpoints:
    """The checkpoints of the run in ``run_dir`` for ``env_id`` / ``algo`` (module docstring)."""

    def __init__(self, run_dir: Path, env_id: str, algo: str):
        self.run_dir = Path(run_dir)
        self.dir = self.run_dir / CHECKPOINT_DIR
        self.env_id, self.algo = env_id, algo

    # -- writing
    def save(self, model, *, tag: str = "", replay_buffer: bool = False, vecnormalize=None, **meta) -> dict:
        """Write checkpoint ``ckpt_<timesteps><tag>`` and point latest.json at it; returns its entry."""
        n = int(model.num_timesteps)
        stem = f"ckpt_{n}{tag}"
        self.dir.mkdir(parents=True, exist_ok=True)
        entry = {"timesteps": n, "model": f"{stem}.zip", "replay_buffer": None, "vecnormalize": None,
                 "env_id": self.env_id, "algo": self.algo, **meta}
        save_model(model, self.dir / entry["model"])
        if replay_buffer:
            entry["replay_buffer"] = f"{stem}_replay_buffer.pkl"
            save_with(model.save_replay_buffer, self.dir / entry["replay_buffer"])
        if vecnormalize is not None:
            entry["vecnormalize"] = f"{stem}_vecnormalize.pkl"
            save_with(vecnormalize, self.dir / entry["vecnormalize"])
        entry["files"] = {entry[k]: _digest(self.dir / entry[k]) for k in _FILE_KEYS if entry.get(k)}
        atomic_json(self.dir / f"{stem}.json", entry)
        atomic_json(self.dir / LATEST, entry)
        self.prune(keep=entry)
        return entry

    def _files_of(self, stem: str) -> list[Path]:
        return [self.dir / f"{stem}{s}" for s in (".zip", ".json", "_replay_buffer.pkl", "_vecnormalize.pkl")]

    def _stems(self) -> list[tuple[int, float, str]]:
        """(timesteps, mtime, stem) of every checkpoint model zip, oldest first."""
        out = []
        for p in self.dir.glob("ckpt_*.zip"):
            m = _NAME.match(p.stem)
            if m:
                out.append((int(m.group(1)), p.stat().st_mtime, p.stem))
        return sorted(out)

    def prune(self, keep: dict) -> None:
        """Keep the newest KEEP_CHECKPOINTS checkpoints (always the one ``keep`` names)."""
        stems = [s for *_, s in self._stems()]
        keep_stem = Path(keep["model"]).stem
        for stem in stems[:-KEEP_CHECKPOINTS]:
            if stem != keep_stem:
                for f in self._files_of(stem):
                    f.unlink(missing_ok=True)

    def discard_after(self, timesteps: int) -> list[str]:
        """Remove the checkpoints newer than ``timesteps`` (a run resumed from an older checkpoint abandons
        them, as it drops their evaluations)."""
        gone = []
        for n, _, stem in self._stems():
            if n > timesteps:
                for f in self._files_of(stem):
                    f.unlink(missing_ok=True)
                gone.append(stem)
        return gone

    # -- reading
    def _entry_of(self, stem: str) -> dict:
        """The entry of checkpoint ``stem``: its sidecar json, or (runs without sidecars) built from the file
        names that exist."""
        side = self.dir / f"{stem}.json"
        if side.exists():
            try:
                return json.loads(side.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError, OSError):
                return {"model": f"{stem}.zip", "timesteps": int(_NAME.match(stem).group(1)), "_bad": side}
        e = {"model": f"{stem}.zip", "timesteps": int(_NAME.match(stem).group(1)), "replay_buffer": None,
             "vecnormalize": None, "env_id": self.env_id, "algo": self.algo}
        for key, suffix in (("replay_buffer", "_replay_buffer.pkl"), ("vecnormalize", "_vecnormalize.pkl")):
            if (self.dir / f"{stem}{suffix}").exists():
                e[key] = f"{stem}{suffix}"
        return e

    def problem(self, entry: dict) -> tuple[Path, str] | None:
        """(file, what is wrong) for the first unusable file of a checkpoint entry, or None if it is intact."""
        if entry.get("_bad") is not None:
            return entry["_bad"], "is not valid JSON (truncated or corrupted)"
        digests = entry.get("files") or {}
        for key in _FILE_KEYS:
            name = entry.get(key)
            if not name:
                continue
            p = self.dir / name
            if not p.exists():
                return p, "is missing"
            want = digests.get(name)
            if want is not None:
                size = p.stat().st_size
                if size != want["bytes"]:
                    return p, f"is damaged: {size} bytes where the checkpoint wrote {want['bytes']}"
                if _digest(p)["sha256"] != want["sha256"]:
                    return p, "is damaged: its SHA-256 differs from the one recorded when it was written"
            else:
                why = _structure_problem(p)
                if why:
                    return p, why
        return None

    def intact(self, before: int | None = None) -> list[dict]:
        """Intact checkpoint entries, newest first (only those older than ``before`` timesteps if given)."""
        out = []
        for n, _, stem in reversed(self._stems()):
            if before is not None and n >= before:
                continue
            e = self._entry_of(stem)
            if self.problem(e) is None:
                out.append(e)
        return out

    def refuse(self, path: Path, why: str, before: int | None = None) -> CheckpointError:
        """The error for a damaged file, offering the newest intact checkpoint (older than ``before``)."""
        ok = self.intact(before)
        if ok:
            stem = Path(ok[0]["model"]).stem
            hint = (f"the last intact checkpoint is {stem} ({ok[0]['timesteps']} timesteps): continue from it "
                    f"with --resume {self.run_dir} --checkpoint {stem}")
        else:
            hint = (f"no intact checkpoint is left: start the run again with --out {self.run_dir} --force")
        return CheckpointError(f"--resume {self.run_dir}: {path} {why}; {hint}")

    def resume_entry(self, name: str | None = None) -> dict:
        """The checkpoint to resume from: ``name`` (e.g. ``ckpt_50000``) or the one latest.json names;
        CheckpointError / FileNotFoundError with a sentence if it is missing, damaged or of another run."""
        if name is not None:
            m = _NAME.match(Path(str(name)).stem)
            if not m or not (self.dir / f"{Path(str(name)).stem}.zip").exists():
                have = [s for *_, s in self._stems()]
                raise CheckpointError(f"--checkpoint {name}: no such checkpoint in {self.dir}; available: "
                                      f"{', '.join(have) if have else 'none'}")
            entry = self._entry_of(Path(str(name)).stem)
            bad = self.problem(entry)
            if bad:
                raise self.refuse(*bad, before=entry["timesteps"])
        else:
            p = self.dir / LATEST
            if not p.exists():
                if self.intact():
                    raise self.refuse(p, "is missing")
                raise FileNotFoundError(f"--resume {self.run_dir}: no checkpoint to resume from ({p} is missing; "
                                        "the run was interrupted before its first checkpoint, start it again with "
                                        "--force)")
            try:
                entry = json.loads(p.read_text())
                if not isinstance(entry, dict) or not isinstance(entry.get("model"), str):
                    raise ValueError("not a checkpoint entry")
                n = int(entry["timesteps"])
            except (json.JSONDecodeError, UnicodeDecodeError, ValueError, KeyError, TypeError):
                raise self.refuse(p, "is not a valid checkpoint pointer (truncated or corrupted JSON)") from None
            bad = self.problem(entry)
            if bad:
                raise self.refuse(*bad, before=n)
        if entry.get("env_id") != self.env_id or entry.get("algo") != self.algo:
            raise CheckpointError(f"{self.dir / entry['model']}: checkpoint of env {entry.get('env_id')!r} / algo "
                                  f"{entry.get('algo')!r} does not match the run's config.json ({self.env_id!r} / "
                                  f"{self.algo!r})")
        return entry
