"""Before / after table of the twin's held-out error (issue 15, docs/diagnosis-history.md round 15): two row files of
``scripts/naming_survey.py`` (the same cases run on two trees) as one Markdown table, in the order of the first,
with the count within the target and the CPU per 10 s recording.

    python scripts/twin_table.py docs/figures/diagnosis/twin_round15/before.jsonl \\
        docs/figures/diagnosis/twin_round15/after.jsonl --labels "main 395ec47" branch
"""
from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

TARGET = 1.5          # the twin target: held-out RMS within this many times the noise the truth added


def read(path: Path) -> list:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def key(r: dict) -> tuple:
    return r.get("case", r["family"]), r["nameplate"], r["seed"]


def ratio(r: dict, k: str = "heldout_rms_after") -> float | None:
    return r[k] / r["true_noise"] if r.get(k) is not None and r.get("true_noise") else None


def cpu10(r: dict) -> float | None:
    return None if r.get("cpu_s") is None else r["cpu_s"] * 10.0 / r.get("duration_s", 6.0)


def cell(r: dict | None) -> str:
    if r is None:
        return "not run"
    if "crash" in r:
        return f"crash: {r['crash']}"
    named = "named" if r.get("named") else "not named"
    return (f"`{r['verdict']}`, {', '.join(r['effects']) or 'none'} ({named}); held-out {ratio(r):.2f}x "
            f"(nominal {ratio(r, 'heldout_rms_before'):.2f}x); cpu {cpu10(r):.0f} s per 10 s")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--labels", nargs=2, default=["before", "after"])
    a = ap.parse_args(argv)
    before, after = read(a.before), {key(r): r for r in read(a.after)}
    print(f"| case | loop | {a.labels[0]} | {a.labels[1]} |\n| --- | --- | --- | --- |")
    for r in before:
        c, n, s = key(r)
        print(f"| {c} s{s} {n} | {'closed' if s % 2 else 'open'} | {cell(r)} | {cell(after.get(key(r)))} |")
    both = [(r, after[key(r)]) for r in before if key(r) in after and "crash" not in r and "crash" not in after[key(r)]]
    for lab, rows in ((a.labels[0], [b for b, _ in both]), (a.labels[1], [x for _, x in both])):
        det = [r for r in rows if r["family"] != "clean"]
        within = sum(ratio(r) <= TARGET for r in det)
        cpus = [cpu10(r) for r in rows if cpu10(r) is not None]
        print(f"\n{lab}: {len(rows)} cases run on both; twin within {TARGET}x on {within}/{len(det)} with an effect; "
              f"cpu per 10 s median {statistics.median(cpus):.0f} s, worst {max(cpus):.0f} s" if cpus else "")
    changed = [key(b) for b, x in both if (b["verdict"], b["effects"], b.get("named")) !=
               (x["verdict"], x["effects"], x.get("named"))]
    print(f"\nnaming or verdict changed on: {changed or 'none'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
