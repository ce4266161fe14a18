"""The etb-gym dispatcher: every subcommand listed, imported only when it runs, its own --help, clear messages
for a subcommand whose module is not in this installation."""
from __future__ import annotations

import subprocess
import sys

import pytest

from etb_gym import cli

NAMES = ["benchmark", "train", "diagnose", "prove", "speed", "reproduce", "design"]


def test_help_lists_every_command_without_importing_them():
    code = ("import sys; from etb_gym.cli import main; rc = main(['--help']); "
            "print('IMPORTED', sorted(m for m in sys.modules if m in %r))" % [m for m, *_ in cli.COMMANDS.values()])
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    for name in NAMES:
        assert f"\n    {name}" in r.stdout, name
    assert "IMPORTED []" in r.stdout
    assert list(cli.COMMANDS) == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_each_command_gives_its_own_help_or_says_it_is_not_installed(name, capsys):
    try:
        fn = cli.resolve(name)
    except cli.CommandUnavailable as exc:
        msg = str(exc)
        assert msg.startswith(f"etb-gym {name}: this installation has no ") and cli.COMMANDS[name][0] in msg
        assert cli.main([name, "--help"]) == 2
        assert capsys.readouterr().err.strip() == msg
        return
    assert callable(fn)
    try:                                    # a main may return argparse's exit code or let SystemExit through
        rc = cli.main([name, "--help"])
    except SystemExit as e:
        rc = e.code
    assert rc == 0
    assert f"usage: etb-gym {name}" in capsys.readouterr().out


def test_missing_module_is_a_sentence_and_a_missing_dependency_is_not_hidden(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(cli.COMMANDS, "speed", ("etb_gym._no_such_module", "x", "scripts/bench_speed.py"))
    assert cli.main(["speed"]) == 2
    err = capsys.readouterr().err
    assert "etb-gym speed: this installation has no module etb_gym._no_such_module" in err
    assert "python scripts/bench_speed.py ARGS" in err
    (tmp_path / "etb_probe_cmd.py").write_text("import etb_no_such_dependency\ndef main(argv):\n    return 0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.COMMANDS, "speed", ("etb_probe_cmd", "x", None))
    with pytest.raises(ModuleNotFoundError, match="etb_no_such_dependency"):
        cli.main(["speed"])


def test_arguments_and_exit_code_pass_through(monkeypatch, tmp_path):
    (tmp_path / "etb_probe_cmd2.py").write_text(
        "import sys\nseen = []\ndef main(argv=None):\n    seen.append((list(argv), sys.argv[0]))\n    return 7\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.COMMANDS, "design", ("etb_probe_cmd2", "x", None))
    assert cli.main(["design", "--gain", "2", "x"]) == 7
    import etb_probe_cmd2

    assert etb_probe_cmd2.seen == [(["--gain", "2", "x"], "etb-gym design")]
    assert sys.argv[0] != "etb-gym design"                  # restored


def test_unknown_command_and_no_command(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["trian"])
    assert e.value.code == 2 and "unknown command 'trian': valid are benchmark, train" in capsys.readouterr().err
    assert cli.main([]) == 2


def test_console_script_runs_a_subcommand():
    r = subprocess.run([sys.executable, "-m", "etb_gym.cli", "reproduce", "--dpi", "5"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "usage: etb-gym reproduce" in r.stderr and "--dpi 5" in r.stderr


def test_the_command_sets_a_sleeping_thread_pool_unless_the_user_chose(monkeypatch, tmp_path):
    (tmp_path / "etb_probe_cmd3.py").write_text(
        "import os\nseen = []\ndef main(argv=None):\n    seen.append(os.environ.get('OMP_WAIT_POLICY'))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.COMMANDS, "design", ("etb_probe_cmd3", "x", None))
    for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER"):
        monkeypatch.delenv(k, raising=False)
    assert cli.main(["design"]) == 0
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    assert cli.main(["design"]) == 0
    import etb_probe_cmd3

    assert etb_probe_cmd3.seen == ["PASSIVE", "ACTIVE"]
