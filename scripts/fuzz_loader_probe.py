#!/usr/bin/env python
"""Loader probe (issue 15, docs/diagnosis.md "Robustness round 10"): odd files of every accepted format
(dtypes, shapes, MATLAB structs and cells, truncated and fake archives, CSV dialects and encodings) through
``load_recording``; each must be read or refused with a RecordingError naming the file, never another
exception. Prints one line per file; exit 1 on a BUG.

    python scripts/fuzz_loader_probe.py [DIR]
"""
import sys
import tempfile
from pathlib import Path

import numpy as np
import scipy.sparse
from scipy.io import savemat

from etb_gym.recordings import RecordingError, load_recording

d = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp(prefix="etb_loader_probe_"))
d.mkdir(parents=True, exist_ok=True)
n = 1200
t = np.arange(n) * 1e-3
rng = np.random.default_rng(0)
a = 5 + 20 * (1 - np.exp(-t * 3)) + 0.01 * rng.normal(size=n)
v = np.where(t > 0.1, 6.0, 0.0)
i = v / 1.25 + 0.01 * rng.normal(size=n)
cases = {}
cases["be.npz"] = lambda p: np.savez(p, time_s=t.astype(">f8"), voltage_V=v.astype(">f8"), angle_deg=a.astype(">f8"))
cases["f32.npz"] = lambda p: np.savez(p, time_s=t.astype("f4"), voltage_V=v.astype("f4"), angle_deg=a.astype("f4"))
cases["f16.npz"] = lambda p: np.savez(p, time_s=t.astype("f2"), voltage_V=v.astype("f2"), angle_deg=a.astype("f2"))
cases["int.npz"] = lambda p: np.savez(p, time_ms=np.arange(n), voltage_V=v.astype(int), angle_deg=np.round(a).astype(np.int16))
cases["bool.npz"] = lambda p: np.savez(p, time_s=t, voltage_V=v > 0, angle_deg=a)
cases["complex.npz"] = lambda p: np.savez(p, time_s=t, voltage_V=v + 0j, angle_deg=a)
cases["obj.npz"] = lambda p: np.savez(p, time_s=np.array(list(t), dtype=object), voltage_V=v, angle_deg=a)
cases["str.npz"] = lambda p: np.savez(p, time_s=t.astype(str), voltage_V=v, angle_deg=a)
cases["col.npz"] = lambda p: np.savez(p, time_s=t[:, None], voltage_V=v[None, :], angle_deg=a[:, None])
cases["3d.npz"] = lambda p: np.savez(p, time_s=t[:, None, None], voltage_V=v, angle_deg=a)
cases["scalar.npz"] = lambda p: np.savez(p, time_s=np.float64(1.0), voltage_V=v, angle_deg=a)
cases["len.npz"] = lambda p: np.savez(p, time_s=t, voltage_V=v[:-5], angle_deg=a)
cases["dup.npz"] = lambda p: np.savez(p, time_s=t, voltage_V=v, angle_deg=a, ANGLE=a, t=t)
cases["empty.npz"] = lambda p: np.savez(p)
cases["u8.npz"] = lambda p: np.savez(p, time_s=t, voltage_V=v.astype(np.uint8), angle_deg=a.astype(np.uint8), current_A=np.abs(i).astype(np.uint8))
cases["row.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": v, "angle_deg": a})
cases["col.mat"] = lambda p: savemat(p, {"time_s": t[:, None], "voltage_V": v[:, None], "angle_deg": a[:, None]}, oned_as="column")
cases["int.mat"] = lambda p: savemat(p, {"time_ms": np.arange(n, dtype=np.int32), "voltage_V": v.astype(np.int8), "angle_deg": a.astype(np.single)})
cases["v4.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": v, "angle_deg": a}, format="4")
cases["struct.mat"] = lambda p: savemat(p, {"rec": {"time_s": t, "voltage_V": v, "angle_deg": a}})
cases["cell.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": v, "angle_deg": np.array([a], dtype=object)})
cases["logical.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": v > 0, "angle_deg": a})
cases["str.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": v, "angle_deg": "abc"})
cases["complex.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": v + 1j, "angle_deg": a})
cases["sparse.mat"] = lambda p: savemat(p, {"time_s": t, "voltage_V": scipy.sparse.csr_matrix(v), "angle_deg": a})
def csv(p, text, enc="utf-8"):
    Path(p).write_bytes(text.encode(enc))



rows = "\n".join(f"{x:.4f},{y:.3f},{z:.4f}" for x, y, z in zip(t, v, a))
cases["plain.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows + "\n")
cases["quoted.csv"] = lambda p: csv(p, '"time_s","voltage_V","angle_deg"\n' + "\n".join(f'"{x:.4f}","{y:.3f}","{z:.4f}"' for x, y, z in zip(t, v, a)))
cases["units.csv"] = lambda p: csv(p, "time [s],voltage [V],angle [deg]\n" + rows)
cases["space.csv"] = lambda p: csv(p, "time_s voltage_V angle_deg\n" + rows.replace(",", " "))
cases["ws.csv"] = lambda p: csv(p, " time_s , voltage_V , angle_deg \n" + rows.replace(",", " , "))
cases["trailing.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg,\n" + rows.replace("\n", ",\n") + ",\n")
cases["blank.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n\n" + rows.replace("\n", "\n\n") + "\n\n\n")
cases["exp.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + "\n".join(f"{x:.6e},{y:.3E},{z:.6e}" for x, y, z in zip(t, v, a)))
cases["utf16.csv"] = lambda p: csv(p, "time_s;voltage_V;angle_deg\r\n" + rows.replace(",", ";").replace(".", ",").replace("\n", "\r\n"), "utf-16")
cases["cr.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\r" + rows.replace("\n", "\r"))
cases["nohdr.csv"] = lambda p: csv(p, rows)
cases["hdronly.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n")
cases["empty.csv"] = lambda p: csv(p, "")
cases["ragged.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows + "\n1.3,2\n")
cases["nan.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows.replace("6.000", "nan", 1))
cases["inf.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows.replace("6.000", "inf", 1))
cases["hex.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows.replace("6.000", "0x6", 1))
cases["under.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows.replace("6.000", "6_0", 1))
cases["huge.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows.replace("6.000", "1e400", 1))
cases["binary.csv"] = lambda p: Path(p).write_bytes(bytes(range(256)) * 10)
cases["latin.csv"] = lambda p: csv(p, "# Prüfstand µ\ntime_s,voltage_V,angle_deg\n" + rows, "cp1252")
cases["dupcol.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg,angle\n" + "\n".join(f"{x:.4f},{y:.3f},{z:.4f},{z:.4f}" for x, y, z in zip(t, v, a)))
cases["slow.csv"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + "\n".join(f"{x*10:.4f},{y:.3f},{z:.4f}" for x, y, z in zip(t, v, a)))
cases["mixedsep.csv"] = lambda p: csv(p, "time_s\tvoltage_V,angle_deg\n" + rows)
cases["dir.csv"] = lambda p: Path(p).mkdir(exist_ok=True)
cases["noext"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows)
cases["upper.CSV"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows)
cases["gz.csv.gz"] = lambda p: csv(p, "x")
cases["trunc.npz"] = lambda p: (np.savez(p, time_s=t, voltage_V=v, angle_deg=a), Path(p).write_bytes(Path(p).read_bytes()[:500]))
cases["trunc.mat"] = lambda p: (savemat(p, {"time_s": t, "voltage_V": v, "angle_deg": a}), Path(p).write_bytes(Path(p).read_bytes()[:300]))
cases["csvasnpz.npz"] = lambda p: csv(p, "time_s,voltage_V,angle_deg\n" + rows)
cases["hdf5.mat"] = lambda p: Path(p).write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 600)
bugs = 0
for name, make in cases.items():
    p = d / name
    try:
        make(str(p))
    except Exception as e:
        print(f"{name:16s} (could not write: {type(e).__name__})")
        continue
    try:
        r = load_recording(p)
        print(f"{name:16s} OK n={r.n} dt={r.dt_s:.3g} ang[{r.angle_deg.min():.2f},{r.angle_deg.max():.2f}] V[{r.voltage_V.min():.2f},{r.voltage_V.max():.2f}] cur={r.current_A is not None}")
    except RecordingError as e:
        m = str(e)
        flag = "" if (name in m or str(p) in m) else "  <-- NO FILE NAME"
        bugs += bool(flag)
        print(f"{name:16s} refused: {m[:200]}{flag}")
    except Exception as e:
        print(f"{name:16s} BUG {type(e).__name__}: {str(e)[:200]}")
        bugs += 1
sys.exit(1 if bugs else 0)
