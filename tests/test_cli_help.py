"""``visphy --help`` lists every command, ``visphy run --help`` the config groups, and a
mistyped command or a ``--flag`` where an override belongs says what to write instead."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from visphy_core.cli.help import config_options
from visphy_core.cli.main import COMMANDS, main


def test_help_lists_every_command_with_one_line(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    listed = [line.split()[0] for line in out.splitlines() if line.startswith("  ")]
    assert listed == list(COMMANDS)
    for name, (_, summary) in COMMANDS.items():
        assert f"{name}" in out and summary in out
    assert "schema_" not in out


def test_run_help_lists_the_config_groups_without_internal_schemas(capsys):
    assert main(["run", "--help"]) == 0
    out = capsys.readouterr().out
    groups = config_options()
    for group in ("dataset", "model", "engine", "metrics", "judge", "tracking"):
        assert f"  {group}: " in out and groups[group]
    assert "threejs*" in out and "mini*" in out and "oracle*" in out   # the defaults
    assert "schema_" not in out and "visphybench_test" in out


@pytest.mark.parametrize("argv, expected", [
    (["reprot", "runs/x"], "unknown command 'reprot'; did you mean 'report'?"),
    (["analyze", "runs"], "did you mean 'analyse'?"),
    (["frobnicate"], "unknown command 'frobnicate' (`visphy --help`"),
    (["--engine", "manim"], "'--engine' is not an option of a run: write overrides as "
                            "key=value, e.g. engine=manim"),
    (["run", "model=oracle", "--dataset=mini"], "e.g. dataset=mini"),
])
def test_a_mistake_is_one_line_with_what_to_write(capsys, argv, expected):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and expected in err and err.count("\n") == 1


def test_the_installed_visphy_command_is_the_same_cli():
    exe = shutil.which("visphy") or str(__import__("pathlib").Path(
        __import__("sys").executable).with_name("visphy"))
    proc = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "usage: visphy [COMMAND] [ARGS]" in proc.stdout


def test_version_is_visphys_not_hydras(capsys):
    from importlib.metadata import version

    assert main(["--version"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"visphy {version('visphy')} (Hydra ")


@pytest.mark.parametrize("command", [c for c in COMMANDS if c != "run"])
def test_every_command_answers_help_with_its_own_usage(capsys, command):
    """``visphy COMMAND --help`` prints that command's usage, named as typed (``visphy
    render``, not ``python -m visphy_core render``), and does nothing else: ``setup --help``
    installs nothing, ``metrics --help`` lists no metric."""
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: visphy {command} [-h]"), out[:300]
    assert "python -m" not in out and "ready in" not in out and "┏" not in out


@pytest.mark.parametrize("argv, expected", [
    (["plugins", "extra"], "unrecognized arguments: extra"),
    (["score"], "the following arguments are required: run_dir\n"),
    (["render", "--engine", "svg"], "the following arguments are required: reply\n"),
])
def test_a_commands_bad_arguments_are_its_usage_and_one_error(capsys, argv, expected):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: visphy {argv[0]} ") and expected in err


@pytest.mark.parametrize("content, expected", [
    (None, "normalise: video not found: "), (b"not a video\n", "normalise: cannot decode video")])
def test_normalise_of_a_missing_or_broken_video_is_one_line(tmp_path, capsys, content, expected):
    video = tmp_path / "in.mp4"
    if content is not None:
        video.write_bytes(content)
    assert main(["normalise", str(video), "--like", str(video), "-o", str(tmp_path / "o.mp4")]) \
        == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {expected}") and err.count("\n") == 1


class _Terminal(__import__("io").StringIO):
    def isatty(self) -> bool:
        return True


def test_plugins_and_metrics_fit_a_narrow_terminal(monkeypatch):
    """On an 80-column terminal the tables wrap their cells to fit it (a fixed 160 columns
    would be wrapped by the terminal into an unreadable grid)."""
    from importlib.metadata import entry_points

    monkeypatch.setenv("COLUMNS", "80")
    for command in ("plugins", "metrics"):
        out = _Terminal()
        monkeypatch.setattr("sys.stdout", out)
        assert main([command]) == 0
        lines = __import__("re").sub(r"\x1b\[[0-9;]*m", "", out.getvalue()).splitlines()
        rows = [line for line in lines if line[:1] in "┏┃┡│└"]  # the table (notes wrap freely)
        assert rows and max(len(row) for row in rows) <= 80
        assert "…" not in "".join(rows).replace("0…", "").replace("1…", "")  # ranges: "0…1"
    names = {ep.name for ep in entry_points(group="visphy")}
    out = _Terminal()
    monkeypatch.setattr("sys.stdout", out)
    main(["plugins"])
    text = out.getvalue()
    assert all(name in text for name in names)
