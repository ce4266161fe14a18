"""Where does a friction candidate's fit start and land? (docs/diagnosis-history.md, "Friction families: the fit's start").

Makes a proof case's recording (no diagnosis), calibrates the nominal model as the diagnosis does, then fits
nominal + CANDIDATE as the screening does (scan of the main parameter, SCREEN_NFEV at SCREEN_SUBSTEPS) and to
convergence (FULL_NFEV at the diagnosis's step), printing the cost of every scan point and where each fit lands.

    python scripts/friction_fit_probe.py stribeck_friction@2 13 --nameplate 3B --candidate stribeck_friction
"""
import argparse
import json
import time
from pathlib import Path


from etb_gym.diagnose import explain as E
from etb_gym.diagnose import fit as F
from etb_gym.diagnose import proof
from etb_gym.diagnose import run as R
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.model import Spec, restart_view


class _Made(Exception):
    pass


def make_case(case, seed, nameplate, workdir):
    """(recordings, Options) of the proof's case, without diagnosing it."""
    got = {}

    def stub(paths, out=None, options=None):
        got.update(paths=paths, options=options)
        raise _Made()

    real = proof.diagnose
    real_rd = proof.record_and_diagnose

    def capture(name, seed, rng, truth, *rest):       # the truth, printed for the analysis only
        got["truth"] = truth
        return real_rd(name, seed, rng, truth, *rest)

    proof.diagnose = stub
    proof.record_and_diagnose = capture
    try:
        opts = proof._parser().parse_args(["--duration", "6", "--jobs", "1", "--nameplate", nameplate])
        proof.run_case(case, seed, opts, str(workdir))
    except _Made:
        pass
    finally:
        proof.diagnose = real
        proof.record_and_diagnose = real_rd
    t = got["truth"]
    print("truth (for the analysis only):", t.friction.params, t.spring.params,
          [e.params for e in t.effects])
    return got["paths"], got["options"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("case")
    ap.add_argument("seed", type=int)
    ap.add_argument("--nameplate", default="3B", choices=("3B", "random"))
    ap.add_argument("--candidate", default="stribeck_friction")
    ap.add_argument("--out", default="out/probe")
    ap.add_argument("--multistart", action="store_true")
    ap.add_argument("--short", type=int, default=0)
    ap.add_argument("--second", type=float, nargs="+", default=[0.01, 0.05, 0.3, 1.0])
    a = ap.parse_args(argv)
    work = Path(a.out) / f"{a.case.replace('@', '_s')}_{a.seed}_{a.nameplate}"
    work.mkdir(parents=True, exist_ok=True)
    paths, opts = make_case(a.case, a.seed, a.nameplate, work)
    recs = R._load(paths)
    base, data = R._base_and_data(R._setup("3B", opts, {}), recs)
    fit_data = restart_view(data)
    t = time.process_time()
    nom = F.calibrate(Spec(base), fit_data, max_nfev=40)
    print(f"calibrated: rss {nom.rss:.1f}, {nom.spec.values(nom.x)}, cpu {time.process_time() - t:.1f} s")
    c = CANDIDATES[a.candidate]
    out = {"case": a.case, "seed": a.seed, "nameplate": a.nameplate, "candidate": a.candidate}
    for label, subst, nfev in (("screen", min(E.SCREEN_SUBSTEPS, base.substeps), E.SCREEN_NFEV),
                               ("full", base.substeps, E.FULL_NFEV)):
        b = base.replace(substeps=subst)
        spec = Spec(b, (c,), nom.spec.nominal)
        x0 = E.extend(nom.x, spec)
        fun = F.make_fun(spec, fit_data)
        lo, hi = spec.bounds()
        k = len(nom.x)
        r0 = fun(x0)
        pts = [(float(x0[k]), float(r0 @ r0))]
        for d in F.scan_offsets(lo[k] - x0[k] + 1e-9, hi[k] - x0[k] - 1e-9):
            x = x0.copy()
            x[k] += d
            r = fun(x)
            pts.append((float(x[k]), float(r @ r)))
        p = spec.params[k][1]
        print(f"[{label}] scan of {p.name}: " + ", ".join(f"{p.init + p.scale * v:.4g}: {c_:.0f}" for v, c_ in pts))
        t = time.process_time()
        fr = F.fit(spec, fit_data, x0, max_nfev=nfev, scan=k)
        vals = fr.spec.values(fr.x)
        print(f"[{label}] fit: rss {fr.rss:.1f} (nominal refit at this step: see scan's first), nfev {fr.nfev}, "
              f"cpu {time.process_time() - t:.1f} s; {json.dumps({n: round(v, 5) for n, v in vals.items()})}")
        out[label] = {"scan": pts, "rss": fr.rss, "values": vals, "nfev": fr.nfev}
        if label == "screen" and a.multistart:      # local fits from a grid of starts (main x second parameter)
            ms = []
            for v, _ in pts:
                for w in a.second:
                    x = x0.copy()
                    x[k] = v
                    if len(spec.params) > k + 1:
                        q = spec.params[k + 1][1]
                        x[k + 1] = min(max((w - q.init) / q.scale, lo[k + 1] + 1e-6), hi[k + 1] - 1e-6)
                    rs = fun(x)
                    if a.short:
                        gs = F.fit(spec, fit_data, x, max_nfev=a.short)
                        print(f"    short ({a.short}): {gs.rss:.0f}")
                    g = F.fit(spec, fit_data, x, max_nfev=nfev)
                    gv = g.spec.values(g.x)
                    ms.append({"start": [p.init + p.scale * v, w], "start_rss": float(rs @ rs), "rss": g.rss,
                               "end": {n.split(".")[-1]: round(val, 5) for n, val in gv.items()}})
                    print(f"  start {p.init + p.scale * v:.4g}, {w:g}: rss {float(rs @ rs):.0f} -> {g.rss:.0f} -> {ms[-1]['end']}")
            out["multistart"] = ms
    with open(work / "probe.json", "w") as fh:
        json.dump(out, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
