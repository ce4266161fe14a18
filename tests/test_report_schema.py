"""The report.json contract: docs/diagnosis-report.md, its JSON Schema, and a real report validated against it."""
from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest

jsonschema = pytest.importorskip("jsonschema")

from etb_gym import make_plant  # noqa: E402
from etb_gym.cli import main as cli_main  # noqa: E402
from etb_gym.components import effects as fx  # noqa: E402
from etb_gym.diagnose.synthetic import make_recording  # noqa: E402
from etb_gym.recordings import save_recording  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / "docs"
SCHEMA = json.loads((DOCS / "diagnosis-report.schema.json").read_text())


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("schema")
    truth = make_plant("3B", substeps=40, effects=[fx.ShaftFluxLoss(loss_at_open_Nm_per_A=0.03, exponent=3.0)])
    save_recording(make_recording(truth, np.random.default_rng(3), duration_s=3.0, name="rig.csv"), tmp / "rig.csv")
    rc = cli_main(["diagnose", str(tmp / "rig.csv"), "--model", "3B", "--out", str(tmp / "diag"), "--quiet",
                   "--jobs", "1", "--max-effects", "1", "--candidates", "shaft_flux_loss", "sensor_quantization"])
    assert rc == 0
    return json.loads((tmp / "diag" / "report.json").read_text())


def test_schema_is_valid_and_requires_the_documented_contract():
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    md = (DOCS / "diagnosis-report.md").read_text()
    example = json.loads(re.search(r"```json\n(.*?)\n```", md, re.S).group(1))
    # a completed report must hold every key of the contract's example; a failed one (verdict "failed") the
    # identification and the reason
    assert set(SCHEMA["required"]) | set(SCHEMA["else"]["required"]) == set(example)
    assert set(SCHEMA["then"]["required"]) == {"reason"}
    extras = md.split("## Extra keys", 1)[1]
    keys = re.findall(r"`([a-z_]+(?:\[\]\.[a-z_0-9]+)?)`", "".join(re.findall(r"^\| (.*?) \|", extras, re.M)))
    assert len(keys) >= 12
    for key in keys:                       # every documented extra key is described by the schema
        props = SCHEMA["properties"]
        if "[]." in key:
            top, sub = key.split("[].")
            props = props[top]["items"]["properties"]
            key = sub
        assert key in props, key


def test_a_real_report_validates(report):
    jsonschema.validate(report, SCHEMA, cls=jsonschema.Draft202012Validator)
    assert report["effects"] and report["effects"][0]["id"] == "shaft_flux_loss"


@pytest.mark.parametrize("mutate", [
    lambda r: r.pop("verdict"),
    lambda r: r.update(verdict="fine"),
    lambda r: r["effects"][0]["parameters"]["exponent"].pop("unit"),
    lambda r: r["mismatch_windows_s"].update({"rig.csv": [[1.0]]}),
    lambda r: r.update(schema="etb-gym/diagnosis/2"),
])
def test_the_schema_rejects_a_broken_report(report, mutate):
    bad = copy.deepcopy(report)
    mutate(bad)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, SCHEMA, cls=jsonschema.Draft202012Validator)
