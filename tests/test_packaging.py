"""Packaging keeps its promises: Python and gymnasium floors, every subpackage installed, the rl extra's TQC,
no backend switch and no process-wide environment change from library code."""
from __future__ import annotations

import ast
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
PROJECT = PYPROJECT["project"]
SETUP = PYPROJECT["tool"]["setuptools"]
# known offenders that their owners are fixing in this round; the lead empties these after merging
MATPLOTLIB_USE_ALLOWED: set = set()


def _floor(req: str) -> tuple:
    return tuple(int(x) for x in req.split(">=", 1)[1].split(",")[0].strip().split("."))


def test_python_floor_is_what_the_code_needs():
    assert PROJECT["requires-python"].strip() == ">=3.11"          # tomllib (plant files)
    assert sys.version_info >= (3, 11)
    src = (ROOT / "etb_gym" / "plantfile.py").read_text()
    assert "import tomllib" in src                                  # stdlib from 3.11: the reason for the floor


def test_gymnasium_floor_has_what_the_vector_env_imports():
    import gymnasium
    from gymnasium.vector import AutoresetMode

    req = next(d for d in PROJECT["dependencies"] if d.startswith("gymnasium"))
    assert _floor(req) == (1, 1)              # AutoresetMode and reset_mask: Gymnasium PR #1227, released in 1.1
    assert tuple(int(x) for x in gymnasium.__version__.split(".")[:2]) >= _floor(req)
    assert AutoresetMode.SAME_STEP and "AutoresetMode" in (ROOT / "envs" / "vector.py").read_text()


def test_every_package_folder_is_installed():
    """Each folder with an __init__.py under a mapped package is listed in [tool.setuptools] packages."""
    listed = set(SETUP["packages"])
    for pkg, folder in SETUP["package-dir"].items():
        assert pkg in listed, pkg
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            name = ".".join([pkg, *rel.parts]) if rel.parts else pkg
            if "__pycache__" not in rel.parts:
                assert name in listed, f"{name} ({init.parent}) is not installed by pyproject.toml"


def test_rl_extra_installs_tqc():
    rl = PROJECT["optional-dependencies"]["rl"]
    assert any(r.startswith("sb3-contrib") for r in rl) and "torch==2.13.0" in rl
    pytest.importorskip("sb3_contrib")
    from etb_gym.rl import algorithm_class, available_algorithms

    assert "tqc" in available_algorithms() and algorithm_class("tqc").__name__ == "TQC"


def test_tqc_trains_a_few_steps(tmp_path):
    pytest.importorskip("sb3_contrib")
    from etb_gym.rl import RLController, RunConfig, train

    cfg = RunConfig(algo="tqc", timesteps=96, n_envs=2, eval_freq=0, checkpoint_freq=10_000, task={"episode_s": 0.1},
                    hyperparams={"learning_starts": 32, "buffer_size": 500, "batch_size": 16, "net_arch": [8, 8]})
    model = train(cfg, tmp_path / "tqc", progress=False, log=lambda *a: None)
    assert model.num_timesteps == 96
    assert RLController(tmp_path / "tqc").config.algo == "tqc"


def _library_files():
    for pkg, folder in SETUP["package-dir"].items():
        if pkg.count(".") <= 1:
            yield from sorted((ROOT / folder).rglob("*.py"))


def _calls_matplotlib_use(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "use" \
                and isinstance(node.func.value, ast.Name) and node.func.value.id in ("matplotlib", "mpl"):
            return True
    return False


def test_no_backend_switch_in_library_code():
    found = {str(p.relative_to(ROOT)) for p in set(_library_files()) if _calls_matplotlib_use(p)}
    assert found - MATPLOTLIB_USE_ALLOWED == set(), "matplotlib.use() in library code; draw on a local Agg canvas"
    assert MATPLOTLIB_USE_ALLOWED - found == set(), "fixed: remove from MATPLOTLIB_USE_ALLOWED"


def _environ_after_import(code: str) -> dict:
    # gymnasium itself sets PYGAME_HIDE_SUPPORT_PROMPT on import: the snapshot is taken after importing it
    r = subprocess.run([sys.executable, "-c", "import os, json, gymnasium; before = dict(os.environ); " + code +
                        "; print(json.dumps({k: v for k, v in os.environ.items() if before.get(k) != v}))"],
                       capture_output=True, text=True, timeout=300,
                       env={k: v for k, v in __import__("os").environ.items()
                            if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER")})
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_importing_the_package_changes_no_environment_variable():
    assert _environ_after_import("import etb_gym, etb_gym.envs, etb_gym.controllers, etb_gym.rl, "
                                 "etb_gym.diagnose, gymnasium as gym; gym.make('ETB-3B-v0')") == {}


def test_readme_test_command_is_what_ci_runs():
    import re

    readme = (ROOT / "README.md").read_text()
    block = re.search(r"Set up and run the tests.*?```bash\n(.*?)\n```", readme, re.S).group(1).strip()
    ci = [ln for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.startswith("python3 -m venv")]
    assert ci == [block]
    assert "ruff check ." in block and "pytest" in block
