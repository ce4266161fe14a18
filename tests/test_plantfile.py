import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.plantfile import load_plant, save_plant


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_plant_file_roundtrip(tmp_path, suffix):
    p = make_plant("2C", {"friction.coulomb_Nm": 0.25, "rotor.inertia_kg_m2": 3.3e-5})
    f = save_plant(p, tmp_path / f"plant{suffix}")
    q = load_plant(f)
    assert q.model == "2C"
    np.testing.assert_array_equal(q.P, p.P)
    d = np.linspace(-0.3, 0.6, 50)
    np.testing.assert_array_equal(q.simulate(d).states, p.simulate(d).states)


def test_plant_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_plant(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text('model = "3B"\n[friction]\nkind = "friction.lugre"\n[friction.params]\nmu = 1.0\n')
    with pytest.raises(ValueError, match=r"bad.toml.*mu"):
        load_plant(bad)
    bad.write_text('model = "3B"\n[friction]\nkind = "friction.magic"\n')
    with pytest.raises(ValueError, match="friction.magic.*valid"):
        load_plant(bad)
