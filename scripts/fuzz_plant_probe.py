#!/usr/bin/env python
"""Plant-file probe (issue 15, docs/diagnosis.md "Robustness round 10"): valid but unusual plant files (no stops,
no spring, no friction, an effect already in the file, switching PWM, a 24 V supply) diagnosing a 1 s clean 3B
recording with two candidates; each must end in a verdict or a ValueError, never another exception.
With ``--effect FAMILY@K`` (round 28) the recording is made by the case's own plant carrying that proof truth
(proof_truth.truth_for at scale 1, 2 s), and FAMILY is the first candidate: the paths that run once an effect is
named (refine, shape tables, twin_range, export) then run on plants without stops, spring or friction.

    nice -n 10 python scripts/fuzz_plant_probe.py ["no spring" ...] [--effect shaft_flux_loss@1]
"""
import json
import sys
import time
import traceback
import warnings

import numpy as np

from etb_gym.components import effects as fx
from etb_gym.diagnose.run import Options, diagnose
from etb_gym.diagnose.synthetic import make_recording
from etb_gym.plant import Plant, make_plant

warnings.simplefilter("ignore")
args = sys.argv[1:]
effect = None
if "--effect" in args:
    k = args.index("--effect")
    effect, args = args[k + 1], args[:k] + args[k + 2:]
which = args
bugs = 0
rng = np.random.default_rng(3)
truth = make_plant("3B", substeps=20)
rec = make_recording(truth, rng, duration_s=1.0, name="r.csv")
base = make_plant("3B").to_dict()


def effect_recording(plant):
    """A 2 s open-loop recording of ``plant`` carrying ``effect`` (the proof's truth at scale 1)."""
    from etb_gym.diagnose.proof_truth import family_shape, tie, truth_for
    fam, shape = family_shape(effect)
    effects, sensor_kw, _, _ = truth_for(fam, np.random.default_rng(7), 1.0, shape)
    t = plant.replace(substeps=20, effects=tuple(plant.effects) + tuple(tie(effects, plant)))
    return make_recording(t, np.random.default_rng(8), duration_s=2.0, name="r.csv", nameplate=plant, **sensor_kw)
def pl(**kw):
    d = json.loads(json.dumps(base))
    d.update(kw)
    return Plant.from_dict(d)



cases = {
 "no stops": lambda: pl(stops=None),
 "no spring": lambda: pl(spring=None),
 "no friction": lambda: pl(friction=None),
 "with flux-loss effect": lambda: make_plant("3B", effects=[fx.ShaftFluxLoss(loss_at_open_Nm_per_A=0.01, exponent=3.0)]),
 "pwm switching": lambda: make_plant("3B", pwm_mode="switching"),
 "supply 24 V": lambda: make_plant("3B", supply_V=24.0),
}
for name in which or cases:
    t0 = time.time()
    try:
        p = cases[name]()
        cands = ("shaft_flux_loss", "spring_asymmetry")
        if effect:
            cands = tuple(dict.fromkeys((effect.partition("@")[0], "spring_asymmetry")))
        res = diagnose([effect_recording(p) if effect else rec],
                       options=Options(plant=p, jobs=1, progress=False, verbose=False, max_effects=1,
                                       candidates=cands))
        print(f"{name}: {res.report['verdict']} {[e['id'] for e in res.report['effects']]} {time.time()-t0:.0f} s", flush=True)
    except ValueError as e:
        print(f"{name}: ValueError {str(e)[:300]} {time.time()-t0:.0f} s", flush=True)
    except Exception as e:
        print(f"{name}: BUG {type(e).__name__}: {str(e)[:300]}", flush=True)
        traceback.print_exc(limit=-4)
        bugs += 1
sys.exit(1 if bugs else 0)
