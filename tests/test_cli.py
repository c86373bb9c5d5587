import subprocess
import sys

from runners.cli import main


def test_help_lists_commands(capsys):
    try:
        main(["--help"])
    except SystemExit as exc:
        assert exc.code == 0
    out = capsys.readouterr().out
    assert "run" in out and "paper" in out


def test_bad_scenario_gives_a_clear_error_and_exit_2(tmp_path, capsys):
    bad = tmp_path / "scenario.toml"
    bad.write_text('[scenario]\nname = "x"\nnetwork = "missing.net.xml"\n[[approaches]]\nname = "a"\n'
                   'route = ["e"]\nmerge_entry_edge = "e"\n')
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "network file not found" in err and "missing.net.xml" in err


def test_console_script_runs(paper_curved_path, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "runners.cli", "run", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "--seed" in proc.stdout


def test_version_names_nrtraffic_and_the_sumo_it_runs():
    """``nrtraffic --version``: the version pyproject.toml declares, and the version the SUMO
    binary reports of itself (``sumo --version``)."""
    import re
    import tomllib

    from conftest import ROOT
    from nrtraffic.sumo.netbuild import sumo_binary

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    binary = subprocess.run([sumo_binary("sumo"), "--version"], capture_output=True, text=True).stdout
    sumo = re.search(r"Eclipse SUMO sumo v?(\d+[._]\d+[._]\d+)", binary).group(1).replace("_", ".")
    proc = subprocess.run([sys.executable, "-m", "runners.cli", "--version"], capture_output=True, text=True,
                          cwd=ROOT, env={**__import__("os").environ, "PYTHONPATH": str(ROOT)}, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == [f"nrtraffic {declared}", f"SUMO {sumo}"]
