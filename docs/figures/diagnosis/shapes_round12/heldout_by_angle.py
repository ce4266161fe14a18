"""The held-out recording of proof case airflow_torque@1 s1 random (6 s), and both twins replayed on it."""
import numpy as np
from etb_gym.diagnose import proof
from etb_gym.diagnose.model import angle_residuals_deg, prepare, simulate
from etb_gym.plantfile import load_plant
recs = []
orig = proof.make_recording
proof.make_recording = lambda *a, **k: recs.append(orig(*a, **k)) or recs[-1]
class Stop(Exception):
    pass
def stop(*a, **k):
    raise Stop
proof.diagnose = stop
opts = proof._parser().parse_args(["--duration", "6", "--jobs", "1", "--nameplate", "random"])
try:
    proof.run_case("airflow_torque@1", 1, opts, "out/held_tmp")
except Stop:
    pass
train, held = recs
print("train range", np.percentile(train.angle_deg, [0, 50, 100]), "held range", np.percentile(held.angle_deg, [0, 1, 50, 99, 100]))
hd = prepare([held], 12.0)
from etb_gym.diagnose.measurement import SensorModel
res = {}
for tag in ("b_airflow", "a1_airflow"):
    p = load_plant(f"out/{tag}/dev_airflow_torque_s1_1/out_airflow_torque_s1_1/calibrated_plant.toml")
    r = angle_residuals_deg(simulate(p, SensorModel(), hd), hd)[0]
    res[tag] = r
    print(tag, [e.kind for e in p.effects], "rms", float(np.sqrt(np.mean(r ** 2))))
a = held.angle_deg
edges = [0, 5, 10, 20, 30, 40, 50, 60, 68.8, 75, 80, 90, 100]
for lo, hi in zip(edges[:-1], edges[1:]):
    m = (a >= lo) & (a < hi)
    if m.sum():
        print(f"{lo:5.1f}-{hi:5.1f} n={m.sum():5d} " + " ".join(f"{t} {np.sqrt(np.mean(res[t][m]**2)):.3f}" for t in res))
