"""Foreign trees as an attacker prepares them: links, special files and oversized files in replay
sources, run directories (re-scored, merged, reported, rated, replayed), dataset folders and
cache entries; a ratings file that is a link; credentials in settings and in a ``.env`` file.

Nothing behind a link may reach any output (rows, artifacts, report, MLflow, stdout/stderr), and
each refusal names the path in one line."""

from __future__ import annotations

import base64
import json
import os
import sqlite3
from pathlib import Path

import pytest

from conftest import run_cli
from visphy_core.infra import files
from visphy_plugins.datasets.tiny import make_tiny_dataset, scene_id
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import ok
from visphy_plugins.testing.replies import reply

#: What an attacker wants: a credential that only the visphy process holds.
DB_URL = "postgres://scott:tiger-canary-5e3a@db.internal/x"
SECRET_TEXT = "canary-file-content-7d1f0b"
BASE = ("tracking=none", "run.progress=false", "dataset=original")


def _env(**extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    env.update(DATABASE_URL=DB_URL, **extra)
    return env


def _tree_text(root: Path) -> str:
    """Every regular file under ``root`` (links not followed), decoded leniently."""
    out = []
    for dirpath, _, names in os.walk(root):
        for name in names:
            path = Path(dirpath) / name
            if path.is_file() and not path.is_symlink():
                out.append(path.read_bytes().decode("utf-8", "replace"))
    return "\n".join(out)


def _assert_clean(*texts: str) -> None:
    for text in texts:
        assert "tiger-canary-5e3a" not in text
        assert SECRET_TEXT not in text
        assert "DATABASE_URL=" not in text


@pytest.fixture
def secret_file(tmp_path) -> Path:
    path = tmp_path / "outside" / "secret.txt"
    path.parent.mkdir()
    path.write_text(f"```html\n<html><!-- {SECRET_TEXT} --></html>\n```\n")
    return path


@pytest.fixture
def tiny(tmp_path) -> Path:
    return make_tiny_dataset(tmp_path / "data", 2)


def _rows(home: Path) -> tuple[Path, dict[str, dict]]:
    (run_dir,) = sorted((home / "runs").iterdir())[-1:]
    rows = {}
    for line in (run_dir / "results.jsonl").read_text().splitlines():
        row = json.loads(line)
        rows[row["scene_id"]] = row
    return run_dir, rows


# ------------------------------------------------------------------ the reader itself
def test_reader_refuses_links_special_files_and_oversized_files(tmp_path, secret_file):
    root = tmp_path / "tree"
    (root / "sub").mkdir(parents=True)
    (root / "ok.txt").write_text("fine")
    (root / "link.txt").symlink_to(secret_file)
    (root / "environ.txt").symlink_to("/proc/self/environ")
    (root / "dirlink").symlink_to(secret_file.parent, target_is_directory=True)
    os.mkfifo(root / "fifo.txt")
    (root / "big.json").write_bytes(b" " * (files.LIMITS["json"] + 1))

    assert files.read_text(root / "ok.txt", root) == "fine"
    for name in ("link.txt", "environ.txt", "dirlink/secret.txt", "fifo.txt", "big.json"):
        with pytest.raises(files.ForeignFileError) as info:
            files.read_bytes(root / name, root, kind="json")
        message = str(info.value)
        assert str(root / name.split("/")[0]) in message and SECRET_TEXT not in message
    with pytest.raises(FileNotFoundError):
        files.read_bytes(root / "missing.txt", root)
    with pytest.raises(files.ForeignFileError):
        files.read_bytes(root / "sub" / ".." / "ok.txt", root)
    with pytest.raises(files.ForeignFileError):
        files.entry_kind(root / "link.txt", root)
    refused = files.scan_tree(root)
    assert set(refused) == {"link.txt", "environ.txt", "dirlink", "fifo.txt", "big.json"}
    # a root that is itself a link is the user's choice and is followed
    alias = tmp_path / "alias"
    alias.symlink_to(root, target_is_directory=True)
    assert files.read_text(alias / "ok.txt", alias) == "fine"


def test_writes_replace_planted_links_and_appends_refuse_them(tmp_path, secret_file):
    run = tmp_path / "run"
    (run / "scenes").mkdir(parents=True)
    before = secret_file.read_bytes()
    (run / "summary.json").symlink_to(secret_file)
    files.atomic_write(run / "summary.json", "{}", run)
    assert not (run / "summary.json").is_symlink() and secret_file.read_bytes() == before
    (run / "scenes" / "s1").symlink_to(secret_file.parent, target_is_directory=True)
    with pytest.raises(files.ForeignFileError):
        files.atomic_write(run / "scenes" / "s1" / "scores.json", "{}", run)
    (run / "ratings.jsonl").symlink_to(secret_file)
    with pytest.raises(files.ForeignFileError):
        files.append_line(run / "ratings.jsonl", "x\n", run)
    os.link(secret_file, run / "hard.jsonl")
    with pytest.raises(files.ForeignFileError):
        files.append_line(run / "hard.jsonl", "x\n", run)
    assert secret_file.read_bytes() == before
    files.append_line(run / "mine.jsonl", "a\n", run)
    files.append_line(run / "mine.jsonl", "b\n", run)
    assert (run / "mine.jsonl").read_text() == "a\nb\n"


# ------------------------------------------------------------------ replay sources
@pytest.mark.parametrize("how", ["file_link", "environ_link", "dir_link"])
def test_replay_through_a_link_is_a_data_error_row_and_reads_nothing(tmp_path, tiny,
                                                                      secret_file, how):
    source, home = tmp_path / "replies", tmp_path / "home"
    source.mkdir()
    good, bad = scene_id(0), scene_id(1)
    (source / f"{good}.txt").write_text(reply("html"))
    if how == "file_link":
        (source / f"{bad}.txt").symlink_to(secret_file)
    elif how == "environ_link":
        (source / f"{bad}.txt").symlink_to("/proc/self/environ")
    else:
        (source / bad).symlink_to(secret_file.parent, target_is_directory=True)
        (secret_file.parent / "response.txt").write_text(secret_file.read_text())
    proc = run_cli("model=replay", f"model.source={source}", *BASE, f"dataset.root={tiny}",
                   home=home, env=_env())
    run_dir, rows = _rows(home)
    assert rows[good]["model_success"] is True
    assert rows[bad]["failure_class"] == "data_error"
    assert str(source / bad) in rows[bad]["failure_detail"]
    assert "symbolic link" in rows[bad]["failure_detail"]
    _assert_clean(_tree_text(run_dir), proc.stdout, proc.stderr)


def _finished_run(tmp_path: Path, tiny: Path) -> tuple[Path, Path]:
    source, home = tmp_path / "replies", tmp_path / "home"
    source.mkdir(exist_ok=True)
    for i in range(2):
        (source / f"{scene_id(i)}.txt").write_text(reply("html"))
    run_cli("model=replay", f"model.source={source}", *BASE, f"dataset.root={tiny}",
            home=home, env=_env())
    run_dir, _ = _rows(home)
    return run_dir, home


def test_replay_of_a_run_with_a_linked_response_is_a_data_error_row(tmp_path, tiny,
                                                                     secret_file):
    run_dir, home = _finished_run(tmp_path, tiny)
    bad = scene_id(1)
    response = run_dir / "scenes" / bad / "response.txt"
    response.unlink()
    response.symlink_to(secret_file)
    proc = run_cli("model=replay", f"model.source={run_dir}", *BASE, f"dataset.root={tiny}",
                   home=home, env=_env())
    replayed, rows = _rows(home)
    assert replayed != run_dir
    assert rows[bad]["failure_class"] == "data_error" and str(response) in \
        rows[bad]["failure_detail"]
    assert rows[scene_id(0)]["model_success"] is True
    _assert_clean(_tree_text(replayed), proc.stdout, proc.stderr)


# ------------------------------------------------------------------ run directories
def test_every_command_that_reads_a_run_refuses_one_with_links(tmp_path, tiny, secret_file):
    run_dir, home = _finished_run(tmp_path, tiny)
    linked = run_dir / "scenes" / scene_id(0) / "analysis.txt"
    linked.unlink(missing_ok=True)
    linked.symlink_to(secret_file)
    for args in (("score", str(run_dir), "metrics.names=[psnr]"), ("report", str(run_dir)),
                 ("merge", str(run_dir), "-o", str(tmp_path / "merged")),
                 ("analyse", str(run_dir), "-o", str(tmp_path / "analysis")),
                 ("rate", str(run_dir), "--rater", "alice", "--port", "0")):
        proc = run_cli(*args, home=home, env=_env(), check=False, timeout=300)
        assert proc.returncode == 2, (args, proc.stdout[-2000:], proc.stderr[-2000:])
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        assert lines[-1].startswith("error: refused to read the run directory"), (args, lines)
        assert str(linked) in lines[-1], (args, lines[-1])
        _assert_clean(proc.stdout, proc.stderr)
    _assert_clean(_tree_text(tmp_path / "home"))


def test_the_rating_store_never_appends_through_a_link(tmp_path, secret_file):
    from visphy_core.human.items import RatingItem
    from visphy_core.human.store import RATINGS_FILE, RatingStore

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / RATINGS_FILE).symlink_to(secret_file)
    before = secret_file.read_bytes()
    item = RatingItem(item="abc", run_dir=run_dir, scene_id="s1", generated=run_dir / "g.mp4",
                      reference=run_dir / "t.mp4")
    store = RatingStore([item])
    with pytest.raises(files.ForeignFileError, match="refused to append"):
        store.append(item, "alice", 4, None)
    assert secret_file.read_bytes() == before


# ------------------------------------------------------------------ dataset folders
def test_a_linked_clip_in_the_original_layout_is_a_data_error_row(tmp_path, tiny, secret_file):
    video = tiny / "sub" / "videos" / f"{scene_id(1)}.mp4"
    video.unlink()
    video.symlink_to(secret_file)
    source, home = tmp_path / "replies", tmp_path / "home"
    source.mkdir()
    for i in range(2):
        (source / f"{scene_id(i)}.txt").write_text(reply("html"))
    run_cli("model=replay", f"model.source={source}", *BASE, f"dataset.root={tiny}",
            home=home, env=_env())
    run_dir, rows = _rows(home)
    assert rows[scene_id(1)]["failure_class"] == "data_error"
    assert str(video) in rows[scene_id(1)]["failure_detail"]
    assert rows[scene_id(0)]["model_success"] is True
    _assert_clean(_tree_text(run_dir))


# ------------------------------------------------------------------ secrets by value
@pytest.mark.parametrize("leak", ["dotenv_key", "url_credentials"])
def test_a_dotenv_key_and_url_credentials_never_reach_any_output(tmp_path, tiny, leak):
    """A hostile provider echoes the Authorization header it was sent (the key read from a
    .env file, never exported; or the SDK's Basic credentials from a URL with user
    information) plus the key itself: neither may appear in the run directory, the MLflow
    store or the console."""
    key = "sk-dotenv-" + "k3y" * 10
    password = "pa55-canary-w0rd"
    home = tmp_path / "home"
    home.mkdir()
    (home / ".env").write_text(f"OPENAI_API_KEY={key}\n")
    seen: list[str] = []

    def echo(req):
        auth = req.headers.get("authorization", "")
        seen.append(auth)
        return ok(reply("html").replace("<html>", f"<html><!-- {auth} {key} -->"))

    server = FakeOpenAIServer(default=echo)
    with server:
        plain = url = server.url + "/v1"
        if leak == "url_credentials":
            url = url.replace("http://", f"http://agent:{password}@")
        proc = run_cli("model=gpt41", f"model.base_url={url}", "dataset=original",
                       f"dataset.root={tiny}", "run.progress=false", home=home, env=_env(),
                       check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # the secret did reach the provider (and so came back in its reply)
    assert seen and seen[0] == (f"Bearer {key}" if leak == "dotenv_key" else
                                "Basic " + base64.b64encode(f"agent:{password}".encode())
                                .decode())
    outputs = [_tree_text(home / "runs"), proc.stdout, proc.stderr]
    db = next(home.rglob("mlflow.db"))
    with sqlite3.connect(db) as con:
        for table in ("params", "tags", "metrics"):
            outputs.append(json.dumps(con.execute(f"select * from {table}").fetchall()))
    outputs += [p.read_bytes().decode("utf-8", "replace") for p in home.rglob("*")
                if p.is_file() and not p.is_symlink() and p.suffix in (".json", ".txt",
                                                                         ".yaml", ".html")]
    for text in outputs:
        assert key not in text
        assert password not in text and seen[0].split()[-1] not in text
    config = next((home / "runs").iterdir()) / "config.yaml"
    assert f"base_url: {plain}\n" in config.read_text()   # stored without credentials


def test_a_binary_dotenv_is_one_line_naming_the_file(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    (home / ".env").write_bytes(b"\xff\xfe\x00\x01OPENAI_API_KEY=\x80\x81")
    proc = run_cli("plugins", home=home, env=_env(), check=False)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == [f"error: {home / '.env'}: the .env file is not UTF-8 text (binary or "
                     "another encoding); it should hold lines NAME=value"]


def test_a_linked_file_in_a_generated_dataset_is_that_scene_data_error(tmp_path, mini_root,
                                                                        secret_file):
    import shutil

    from visphy_plugins.datasets.visphybench.loader import load_generated

    root = tmp_path / mini_root.name
    shutil.copytree(mini_root, root)
    scenes = load_generated(root, split="mini", strict=False)
    bad = scenes[1].scene_id
    spec = root / "specs" / f"{bad}.json"
    spec.unlink()
    spec.symlink_to(secret_file)
    scenes = {s.scene_id: s for s in load_generated(root, split="mini", strict=False)}
    assert scenes[bad].load_error.startswith(f"refused to read {spec}: it is a symbolic link")
    assert all(s.load_error is None for sid, s in scenes.items() if sid != bad)
    with pytest.raises(files.ForeignFileError):
        load_generated(root, split="mini", strict=True)
    (root / "metadata.jsonl").rename(root / "meta.real")
    (root / "metadata.jsonl").symlink_to(root / "meta.real")
    with pytest.raises(files.ForeignFileError, match="metadata.jsonl"):
        load_generated(root, split="mini", strict=False)
