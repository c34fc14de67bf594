"""The ``hallray`` command (hallray.main): its subcommands are the tools themselves (same options,
same one-line errors, same exit statuses), its help is cheap, the old names stay."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

from hallray.main import BY_NAME, SUBCOMMANDS, main, usage

ROOT = Path(__file__).resolve().parents[2]


def test_help_lists_every_subcommand_without_importing_the_packages():
    code = (
        "import sys\n"
        "from hallray.main import main\n"
        "assert main(['--help']) == 0\n"
        "bad = sorted(m for m in sys.modules\n"
        "             if m.split('.')[0] in ('raytrace', 'positioning', 'numpy', 'numba'))\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    *text, imported = out.stdout.strip().splitlines()
    assert imported == "[]"
    listed = [line.split()[0] for line in text if line.startswith("  ")]
    assert listed == [s.name for s in SUBCOMMANDS]
    wanted = {"trace", "dataset", "positions", "report", "map", "paper", "view", "render", "scan",
              "build-hall", "make-hall", "sweep", "export"}  # issue 39  # fmt: skip
    assert wanted <= set(listed)


def test_every_subcommand_is_a_console_script_with_the_same_entry_point():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["hallray"] == "hallray.main:main"
    for s in SUBCOMMANDS:
        assert scripts[s.script] == s.target, s.name
    # every tool's console script is reachable as a subcommand
    assert {v for k, v in scripts.items() if k != "hallray"} == {s.target for s in SUBCOMMANDS}


@pytest.mark.parametrize("sub", SUBCOMMANDS, ids=lambda s: s.name)
def test_subcommand_help_is_the_tools_help_under_the_hallray_name(sub, capsys):
    assert main([sub.name, "--help"]) == 0
    mine = capsys.readouterr().out
    assert mine.startswith(f"usage: hallray {sub.name} ")
    assert sub.entry()(["--help"]) == 0  # the tool alone keeps its own name afterwards
    theirs = capsys.readouterr().out
    assert theirs.startswith(f"usage: {sub.script} ")
    # the same options and text: only the program name differs
    assert mine.replace(f"hallray {sub.name}", sub.script).split() == theirs.split()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["dataset", "--scenario", "static", "-o", "{tmp}/d"], "give --scenario and --band"),
        (["dataset", "--all", "--receiver", "psychic", "-o", "{tmp}/d"], "ToA method"),
        (["map", "hall", "--step", "0", "-o", "{tmp}/m"], "--step"),
        (["trace", "no-such-scene.glb"], "no-such-scene.glb"),
        (["positions", "{tmp}/nowhere", "-o", "{tmp}/f.csv"], "nowhere"),
        (["report", "{tmp}/nowhere", "-o", "{tmp}/r"], "nowhere"),
        (["paper", "--workers", "0", "-o", "{tmp}/p"], "--workers"),
        (["sweep", "{tmp}/none.yaml"], "none.yaml"),
        (["build-hall", "{tmp}/none.yaml"], "none.yaml"),
        (["make-hall", "--profile", "InF-XX", "-o", "{tmp}/h"], "InF-XX"),
        (["trace", "hall", "--frobnicate"], "unrecognized arguments"),
    ],
)
def test_bad_input_is_the_tools_one_line_error(tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("error: ") and "\n" not in err, err
    assert message in err
    # the tool under its own name says exactly the same
    assert BY_NAME[argv[0]].entry()(argv[1:]) == code
    assert capsys.readouterr().err.strip() == err
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_unknown_or_missing_subcommand(capsys):
    assert main(["trac"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("error: unknown subcommand 'trac' (did you mean 'trace'?); 'hallray --help' "
                   "lists the subcommands")  # fmt: skip
    assert main(["--frobnicate"]) == 2
    assert capsys.readouterr().err.strip().startswith("error: unknown option '--frobnicate'")
    assert main([]) == 2
    err = capsys.readouterr().err
    assert usage() in err and err.strip().endswith("error: missing SUBCOMMAND")


def test_help_and_version_and_old_names(capsys):
    assert main(["help", "map"]) == 0
    assert capsys.readouterr().out.startswith("usage: hallray map ")
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("hallray ")
    assert main(["accuracy-map", "--help"]) == 0  # a tool's old name is a subcommand too
    assert capsys.readouterr().out.startswith("usage: hallray map ")


@pytest.mark.parametrize(
    ("argv", "old", "new"),
    [
        (["dataset", "--all", "-q", "-o", "{tmp}/d"], ["--toa-method", "psychic"],
         ["--receiver", "psychic"]),
        (["map", "hall", "--receiver", "leading-edge", "-o", "{tmp}/m"], ["--paths", "4"],
         ["--paths-per-link", "4"]),
        (["map", "hall", "-o", "{tmp}/m"], ["--methods", "ls", "magic"],
         ["--methods", "ls,magic"]),
        (["los-check", "InF-SL", "--seeds", "1", "--points", "5"], ["--plot", "{tmp}/x.txt"],
         ["-o", "{tmp}/x.txt"]),
    ],
)
def test_old_and_new_spellings_of_an_option_are_the_same(tmp_path, capsys, argv, old, new):
    results = []
    for opt in (old, new):
        full = [a.replace("{tmp}", str(tmp_path)) for a in [*argv, *opt]]
        code = main(full)
        results.append((code, capsys.readouterr().err.strip()))
    assert results[0] == results[1]
    assert results[0][0] == 2 and results[0][1].startswith("error: ")
    assert list(tmp_path.iterdir()) == []
