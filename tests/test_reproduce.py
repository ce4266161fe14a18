"""etb-gym reproduce (etb_gym.paper; scripts/reproduce_paper.py wraps it): runs as a CLI and writes valid,
non-blank PNGs plus figures.md."""
import re
import struct
import subprocess
import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "reproduce_paper.py"
PNGS = {"8": "fig08_electric_drive.png", "12": "fig12_presliding.png", "13": "fig13_release.png",
        "14": "fig14_steps_1A_3B.png", "15": "fig15_steps_2B_3B.png"}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120,
                          cwd=ROOT)


def png_size(path: Path):
    """(width, height) from the IHDR chunk; fails unless the file starts like a PNG."""
    head = path.read_bytes()[:24]
    assert head[:8] == PNG_SIGNATURE, f"{path.name} is not a PNG"
    assert head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    r = run("--out", str(out), "--dpi", "40", "--no-progress")
    assert r.returncode == 0, r.stderr
    return out, r.stdout


@pytest.fixture(scope="module")
def script_main():
    from etb_gym.paper import main

    return main


def test_all_figures_written_as_valid_pngs(generated):
    out, _ = generated
    for fig, name in PNGS.items():
        path = out / name
        assert path.is_file(), f"Fig. {fig}: {name} missing"
        w, h = png_size(path)
        assert 200 <= w <= 600 and 150 <= h <= 600, (name, w, h)     # 8 in wide at 40 dpi = 320 px
        img = matplotlib.image.imread(path)                           # decodes every scanline
        assert img.shape[:2] == (h, w)
        assert np.ptp(img[..., :3]) > 0.5, f"{name} looks blank"       # has dark lines on white
    assert not list(out.glob(".*")), "temporary files left behind"


def test_one_line_per_figure_printed_and_in_figures_md(generated):
    out, stdout = generated
    printed = [ln for ln in stdout.splitlines() if ln.startswith("Fig. ")]
    assert [re.match(r"Fig\. (\d+)", ln).group(1) for ln in printed] == list(PNGS)
    md = (out / "figures.md").read_text()
    for fig, name in PNGS.items():
        assert f"- Fig. {fig} ({name}" in md
        assert f"]({name})" in md                                     # the image is linked
    assert all(ln in md for ln in printed)
    assert "no measurements" in md                                   # Figs. 14, 15 say so


def test_only_regenerates_selection_and_keeps_other_lines(script_main, tmp_path):
    assert script_main(["--out", str(tmp_path), "--only", "13", "--dpi", "30", "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.glob("*.png")) == [PNGS["13"]]
    md = (tmp_path / "figures.md").read_text()
    assert "- Fig. 13 (" in md and "Fig. 8" not in md
    # a second selection adds its line and keeps Fig. 13's (its PNG is still there)
    assert script_main(["--out", str(tmp_path), "--only", "15", "--dpi", "30", "--no-progress"]) == 0
    md = (tmp_path / "figures.md").read_text()
    assert "- Fig. 13 (" in md and "- Fig. 15 (" in md
    assert md.index("- Fig. 13 (") < md.index("- Fig. 15 (")


@pytest.mark.parametrize("args, code, text", [
    (["--help"], 0, "out/paper"),
    (["--only", "9"], 2, "invalid choice"),
    (["--dpi", "5"], 2, "--dpi 5: expected"),
])
def test_help_and_bad_arguments(script_main, capsys, args, code, text):
    with pytest.raises(SystemExit) as e:
        script_main(args)
    assert e.value.code == code
    cap = capsys.readouterr()
    assert text in (cap.out if code == 0 else cap.err)


def test_committed_figures_are_small():
    folder = ROOT / "docs" / "figures" / "paper"
    for name in PNGS.values():
        path = folder / name
        assert path.is_file(), f"{path} is not committed; run etb-gym reproduce --out docs/figures/paper"
        png_size(path)
        assert path.stat().st_size < 200_000, (name, path.stat().st_size)
