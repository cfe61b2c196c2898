"""Reference descriptions, the `replay` model and the one-reply `render` command.

* `visphy_core/calls/references.py`: `describe_spec` / `describe_detection` are deterministic, name
  exactly what the ground truth holds and tell scenes apart; `ReferenceWriter` (``spec`` mode)
  caches by the scene's ground truth (shared by every run and model) and never reads a reply.
* `plugins/models/replay.py`: every source layout it documents (a folder of ``<id>.txt`` /
  ``.md`` / ``.html`` / ``.py``, bare programs, ``.attempt2`` repair replies, one sub-folder per
  scene, a run directory, a folder of videos, a single file), directly and through the real CLI;
  a scene without a recorded reply is a counted ``model_error`` row.
* ``python -m visphy_core render REPLY ...``: a good reply renders and is scored, a reply
  without a program or an unknown scene id is one clear line and a non-zero exit.

Real specs come from `mini_templates (tests/mini_templates.py).mini_specs()` (the hand-made 2D
scenes,
simulated and annotated by the benchmark's own annotator: contact events included), which costs
under a second, instead of the `mini_scenes` fixture (which simulates the whole catalogue,
~50 s). CLI runs use `make_tiny_dataset` (64x64, 17 frames).
"""

from __future__ import annotations

import copy
import json
import re
import shutil
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from conftest import run_cli
from visphy_core.api.errors import UserError
from visphy_core.api.model import ModelRequest, OutputContract
from visphy_core.api.scene import Scene
from visphy_core.calls.references import ReferenceWriter, describe_detection, describe_spec
from visphy_core.infra.cache import Cache
from visphy_core.infra.video import ClipInfo
from visphy_plugins.datasets.tiny import make_tiny_dataset, scene_id
from visphy_plugins.models.replay import ReplayConfig, ReplayModel
from visphy_plugins.testing.replies import ANALYSIS, HTML_PROGRAM, MANIM_PROGRAM, reply

S0, S1, S2, S3 = (scene_id(i) for i in range(4))


# =============================================================================== references


@pytest.fixture(scope="module")
def specs() -> list[dict]:
    from mini_templates import mini_specs

    return mini_specs()


def _listed_objects(text: str) -> tuple[int, list[str]]:
    m = re.match(r"The scene contains (\d+) objects?: (.*?)\. ", text)
    assert m, text
    return int(m.group(1)), re.split(r", | and ", m.group(2))


def _pairs(spec: dict) -> list[str]:
    out = []
    for ev in spec["ground_truth"]["events"]:
        if ev["type"] == "contact_begin":
            pair = f"{ev['a'].replace('_', ' ')} and {ev['b'].replace('_', ' ')}"
            if pair not in out:
                out.append(pair)
    return out


def test_describe_spec_is_deterministic(specs):
    for spec in specs:
        text = describe_spec(spec)
        assert text and text == describe_spec(copy.deepcopy(spec))
        assert text == describe_spec(json.loads(json.dumps(spec)))  # as read back from disk


def test_describe_spec_names_exactly_the_bodies_and_contacts_of_the_spec(specs):
    for spec in specs:
        text = describe_spec(spec)
        n, names = _listed_objects(text)
        bodies = spec["bodies"]
        assert n == len(bodies)
        assert sorted(names) == sorted(b["id"].replace("_", " ") for b in bodies)
        dynamic = [b["id"].replace("_", " ") for b in bodies if b["dynamic"]]
        m = re.search(r"The dynamic (?:body is|bodies are) (.*?); ", text)
        assert m and sorted(re.split(r", | and ", m.group(1))) == sorted(dynamic)
        # every collision named is a contact_begin of the ground truth (first six pairs, in order)
        m = re.search(r"Collisions occur between (.*?)(?: \(the first after ([\d.]+) s\))?\.",
                      text)
        assert m, text
        assert m.group(1).split("; ") == _pairs(spec)[:6]
        first = next(e["t_s"] for e in spec["ground_truth"]["events"]
                     if e["type"] == "contact_begin")
        assert m.group(2) == f"{first:.1f}"
        g = (sum(c ** 2 for c in spec["world"]["gravity_m_s2"])) ** 0.5
        assert f"Gravity of {g:.3g} m/s²" in text


def test_describe_spec_tells_scenes_apart(specs):
    texts = [describe_spec(s) for s in specs]
    assert len(set(texts)) == len(specs)


def test_describe_spec_follows_the_physics_of_the_spec(specs):
    base = specs[0]
    text = describe_spec(base)
    assert "start at rest" in text and "initial velocity" not in text

    launched = copy.deepcopy(base)
    launched["bodies"][0]["velocity"]["vx_px_s"] = 50.0
    t = describe_spec(launched)
    assert t != text and t.startswith(text.split(" All dynamic")[0])
    assert "Red ball starts with an initial velocity while" in t

    quiet = copy.deepcopy(base)
    quiet["ground_truth"]["events"] = []
    t = describe_spec(quiet)
    assert "Collisions" not in t and "touch nothing" in t

    frozen = copy.deepcopy(base)
    for b in frozen["bodies"]:
        b["dynamic"] = False
    t = describe_spec(frozen)
    assert "nothing moves" in t and "Gravity" not in t and "dynamic bodies are" not in t

    moon = copy.deepcopy(base)
    moon["world"]["gravity_m_s2"] = [0.0, -1.62]
    assert "Gravity of 1.62 m/s²" in describe_spec(moon)

    renamed = copy.deepcopy(base)
    renamed["bodies"][0]["id"] = "orange_puck"
    t = describe_spec(renamed)
    assert "orange puck" in t and "red ball" not in _listed_objects(t)[1]


def test_describe_detection_is_deterministic_and_lists_the_objects():
    det = {"objects": [{"id": "red_ball", "category": "circle"},
                       {"id": "green_bar", "category": "bar"}]}
    text = describe_detection(det)
    assert text == describe_detection(copy.deepcopy(det))
    assert text == "The scene contains 2 objects: red ball (circle), green bar (bar)."
    other = {"objects": [{"id": "red_ball", "category": "circle"}]}
    assert describe_detection(other) != text
    assert describe_detection({"objects": []}) == "The scene contains no detected objects."


def _cfg(source: str = "spec"):
    return OmegaConf.create({"source": source, "model": None, "frames": 8})


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory) -> Path:
    return make_tiny_dataset(tmp_path_factory.mktemp("tiny"), 4)


def _spec_scene(folder: Path, spec: dict, video: Path, detection: dict | None = None) -> Scene:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "spec.json").write_text(json.dumps(spec))
    shutil.copyfile(video, folder / "video.mp4")
    det_path = None
    if detection is not None:
        det_path = folder / "detection.json"
        det_path.write_text(json.dumps(detection))
    return Scene(scene_id=spec["scene_id"], dim="2d", clip=ClipInfo(5.0, 17, 512, 512),
                 video_path=folder / "video.mp4", spec_path=folder / "spec.json",
                 detection_path=det_path)


def _detection_scene(folder: Path, sid: str, video: Path, detection: dict) -> Scene:
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(video, folder / "video.mp4")
    (folder / "detection.json").write_text(json.dumps(detection))
    return Scene(scene_id=sid, dim="2d", clip=ClipInfo(5.0, 17, 64, 64),
                 video_path=folder / "video.mp4", detection_path=folder / "detection.json")


def _replay(source: Path, output: str | None = None) -> ReplayModel:
    return ReplayModel(OmegaConf.structured(ReplayConfig(name="replay", source=str(source),
                                                         output=output)))


def test_reference_writer_spec_mode_caches_by_ground_truth_for_every_run(tmp_path, specs,
                                                                          tiny_root):
    video = tiny_root / "sub" / "videos" / f"{S0}.mp4"
    spec = specs[1]
    scene = _spec_scene(tmp_path / "a", spec, video,
                        detection={"objects": [{"id": "x", "category": "circle"}]})
    cache = Cache(tmp_path / "cache")
    assert ReferenceWriter(_cfg(), cache).describe(scene) == (describe_spec(spec), "spec")
    assert cache.stats()["reference"] == {"hits": 0, "misses": 1}
    (entry,) = [p for p in (tmp_path / "cache" / "reference").rglob("reference.json")]
    assert json.loads(entry.read_text()) == {"source": "spec", "text": describe_spec(spec)}

    # A later run (a new Cache on the same root) and the same ground truth copied elsewhere
    # (another dataset folder): the entry is shared, nothing is written again.
    again = Cache(tmp_path / "cache")
    copy_scene = _spec_scene(tmp_path / "b", spec, video)
    assert ReferenceWriter(_cfg(), again).describe(copy_scene) == (describe_spec(spec), "spec")
    assert again.stats()["reference"] == {"hits": 1, "misses": 0}

    # Other ground truth: a new entry with its own text.
    other = _spec_scene(tmp_path / "c", specs[2], video)
    text, _ = ReferenceWriter(_cfg(), again).describe(other)
    assert text == describe_spec(specs[2]) != describe_spec(spec)
    assert again.stats()["reference"] == {"hits": 1, "misses": 1}

    # The spec file edited in place: the key follows the content, so the text is rewritten.
    edited = copy.deepcopy(spec)
    edited["world"]["gravity_m_s2"] = [0.0, -3.0]
    (tmp_path / "a" / "spec.json").write_text(json.dumps(edited))
    fresh = Scene(scene_id=scene.scene_id, dim="2d", clip=scene.clip,
                  video_path=scene.video_path, spec_path=scene.spec_path)
    text, _ = ReferenceWriter(_cfg(), Cache(tmp_path / "cache")).describe(fresh)
    assert "Gravity of 3 m/s²" in text and text == describe_spec(edited)


def test_reference_writer_never_reads_the_model(tmp_path, specs, tiny_root):
    """In spec mode the writer ignores any model it is handed: the text is the spec's, whatever
    the model would say, and two different models read the same cache entry."""
    from visphy_core.calls.generation import ModelCaller
    from visphy_core.calls.usage import UsageLedger

    spec = specs[3]
    scene = _spec_scene(tmp_path / "s", spec, tiny_root / "sub" / "videos" / f"{S1}.mp4")
    cache = Cache(tmp_path / "cache")
    texts, identities = [], []
    for i, words in enumerate(("The model says: a purple elephant flies.", ANALYSIS)):
        replies = tmp_path / f"replies{i}"
        replies.mkdir()
        (replies / f"{scene.scene_id}.txt").write_text(words)
        model = _replay(replies)
        ledger = UsageLedger(tmp_path / f"calls{i}.jsonl")
        writer = ReferenceWriter(_cfg(), cache, model, ModelCaller(model, cache, ledger))
        identities.append(writer.identity())
        text, source = writer.describe(scene)
        assert source == "spec" and words not in text and "elephant" not in text
        assert ledger.totals() == {}  # no call of any stage was made
        texts.append(text)
    assert texts == [describe_spec(spec)] * 2
    assert identities[0] == identities[1] and identities[0].startswith("spec:")
    assert cache.stats()["reference"] == {"hits": 1, "misses": 1}
    assert "response" not in cache.stats()


def test_reference_writer_without_a_spec_describes_the_detection(tmp_path, tiny_root):
    det = json.loads((tiny_root / "sub" / "detection_json" / f"{S0}_frame_01.json").read_text())
    scene = _detection_scene(tmp_path / "d", S0, tiny_root / "sub" / "videos" / f"{S0}.mp4",
                             det)
    text, source = ReferenceWriter(_cfg(), Cache(tmp_path / "cache")).describe(scene)
    assert (text, source) == (describe_detection(det), "detection")
    assert "falling square (rectangle)" in text
    bare = Scene(scene_id=S2, dim="2d", clip=ClipInfo(5.0, 17, 64, 64),
                 video_path=tiny_root / "sub" / "videos" / f"{S2}.mp4")
    assert ReferenceWriter(_cfg(), Cache(tmp_path / "cache")).describe(bare) == ("", "none")


def test_reference_cache_key_covers_the_detection_it_describes(tmp_path, tiny_root):
    video = tiny_root / "sub" / "videos" / f"{S0}.mp4"
    first = {"objects": [{"id": "falling_square", "category": "rectangle"}]}
    second = {"objects": [{"id": "blue_ball", "category": "circle"},
                          {"id": "black_bar", "category": "bar"}]}
    cache = Cache(tmp_path / "cache")
    a = _detection_scene(tmp_path / "v1", S0, video, first)
    b = _detection_scene(tmp_path / "v2", S0, video, second)   # same clip, new detection
    assert ReferenceWriter(_cfg(), cache).describe(a)[0] == describe_detection(first)
    assert ReferenceWriter(_cfg(), cache).describe(b)[0] == describe_detection(second)


# =============================================================================== replay model


def _request(sid: str, attempt: int = 1, language: str = "html") -> ModelRequest:
    return ModelRequest(scene_id=sid, prompt="p", images=[], detection=None,
                        engine_name="threejs", language=language,
                        output=OutputContract(5.0, 17, 64, 64), attempt=attempt,
                        stage="generate" if attempt == 1 else "repair")


def test_replay_folder_of_reply_files_every_suffix(tmp_path):
    src = tmp_path / "replies"
    src.mkdir()
    (src / "task00001_000.txt").write_text(reply("html"))
    (src / "task00002_000.md").write_text("# notes\n" + reply("html"))
    (src / "task00003_000.html").write_text(HTML_PROGRAM)                 # bare program
    (src / "task00004_000.py").write_text(MANIM_PROGRAM)                  # bare program
    (src / "task00005_000.html").write_text(f"```html\n{HTML_PROGRAM}\n```\n")  # fenced already
    (src / "task00006_000.txt").write_text(HTML_PROGRAM)                  # .txt: never wrapped
    model = _replay(src)
    model.check_ready()
    assert model.output_kind == "program"
    text = {sid: model.generate(_request(sid)) for sid in
            [f"task0000{i}_000" for i in range(1, 7)]}
    assert all(r.error is None and r.cost_usd == 0.0 for r in text.values())
    assert text["task00001_000"].text == reply("html")
    assert text["task00002_000"].text == "# notes\n" + reply("html")
    assert text["task00003_000"].text == f"```html\n{HTML_PROGRAM.rstrip()}\n```\n"
    assert text["task00004_000"].text == f"```python\n{MANIM_PROGRAM.rstrip()}\n```\n"
    assert text["task00005_000"].text == f"```html\n{HTML_PROGRAM}\n```\n"
    assert text["task00006_000"].text == HTML_PROGRAM


def test_replay_wrapped_bare_program_extracts_unchanged(tmp_path):
    from visphy_core.api.extract import extract_code

    src = tmp_path / "r"
    src.mkdir()
    (src / f"{S0}.html").write_text(HTML_PROGRAM)
    (src / f"{S1}.py").write_text(MANIM_PROGRAM)
    model = _replay(src)
    assert extract_code(model.generate(_request(S0)).text, ("html",)).strip() == \
        HTML_PROGRAM.strip()
    assert extract_code(model.generate(_request(S1)).text, ("python", "py")).strip() == \
        MANIM_PROGRAM.strip()


def test_replay_repair_replies_and_missing_ones(tmp_path):
    src = tmp_path / "replies"
    src.mkdir()
    (src / f"{S0}.txt").write_text("first try, no code")
    (src / f"{S0}.attempt2.txt").write_text(reply("html"))
    (src / f"{S1}.txt").write_text("only one try")
    model = _replay(src)
    assert model.generate(_request(S0)).text == "first try, no code"
    assert model.generate(_request(S0, attempt=2)).text == reply("html")
    second = model.generate(_request(S1, attempt=2))
    assert second.error_kind == "not_recorded" and "attempt 2" in second.error
    assert S1 in second.error
    missing = model.generate(_request(S2))
    assert missing.error_kind == "not_recorded" and missing.text == ""
    assert f"no recorded reply for {S2}" in missing.error
    assert str(src / f"{S2}.txt") in missing.error


def test_replay_one_sub_folder_per_scene(tmp_path):
    src = tmp_path / "replies"
    (src / S0).mkdir(parents=True)
    (src / S0 / "response.txt").write_text("the response")
    (src / S0 / "aaa_notes.md").write_text("not this one")      # response.txt comes first
    (src / S0 / "response.attempt2.txt").write_text("the repair")
    (src / S1).mkdir()
    (src / S1 / "gpt_answer.html").write_text(HTML_PROGRAM)      # the only reply file: bare
    (src / S1 / "reply.attempt2.md").write_text("a repair is never a first reply")
    (src / S2).mkdir()                                            # an empty folder
    model = _replay(src)
    assert model.generate(_request(S0)).text == "the response"
    assert model.generate(_request(S0, attempt=2)).text == "the repair"
    assert model.generate(_request(S1)).text == f"```html\n{HTML_PROGRAM.rstrip()}\n```\n"
    assert model.generate(_request(S2)).error_kind == "not_recorded"


def test_replay_run_directory_layout_and_output_from_manifest(tmp_path):
    run = tmp_path / "run"
    (run / "scenes" / S0).mkdir(parents=True)
    (run / "manifest.json").write_text(json.dumps({"model": {"name": "gpt5",
                                                             "output": "program"}}))
    (run / "scenes" / S0 / "response.txt").write_text("reply one")
    (run / "scenes" / S0 / "response.attempt2.txt").write_text("reply two")
    (run / "scenes" / S0 / "video.mp4").write_bytes(b"a rendered clip is not a reply")
    model = _replay(run)
    assert model.output_kind == "program"
    assert model.generate(_request(S0)).text == "reply one"
    assert model.generate(_request(S0, attempt=2)).text == "reply two"
    r = model.generate(_request(S1))
    assert r.error_kind == "not_recorded" and str(run / "scenes" / S1 / "response.txt") in r.error

    (run / "manifest.json").write_text(json.dumps({"model": {"name": "svd", "output": "video"}}))
    video = _replay(run)
    assert video.output_kind == "video"
    got = video.generate(_request(S0))
    assert got.error is None and got.video_path == str(run / "scenes" / S0 / "video.mp4")
    assert video.generate(_request(S0, attempt=2)).error_kind == "not_recorded"


def test_replay_folder_of_videos(tmp_path, tiny_root):
    src = tmp_path / "videos"
    src.mkdir()
    shutil.copyfile(tiny_root / "sub" / "videos" / f"{S0}.mp4", src / f"{S0}.mp4")
    model = _replay(src)
    assert model.output_kind == "video"
    r = model.generate(_request(S0))
    assert r.error is None and r.video_path == str(src / f"{S0}.mp4")
    assert model.generate(_request(S1)).error_kind == "not_recorded"
    # a reply file beside the videos makes it a folder of replies again (model.output wins)
    (src / f"{S1}.txt").write_text(reply("html"))
    assert _replay(src).output_kind == "program"
    assert _replay(src, output="video").generate(_request(S0)).video_path == str(
        src / f"{S0}.mp4")


def test_replay_single_file_answers_every_scene_once(tmp_path):
    one = tmp_path / "reply.md"
    one.write_text(reply("html"))
    model = _replay(one)
    assert model.generate(_request(S0)).text == reply("html")
    assert model.generate(_request(S3)).text == reply("html")
    assert model.generate(_request(S0, attempt=2)).error_kind == "not_recorded"


def test_replay_identity_follows_the_recorded_replies(tmp_path):
    src = tmp_path / "replies"
    src.mkdir()
    (src / f"{S0}.txt").write_text("a")
    first = _replay(src).identity()
    assert _replay(src).identity() == first
    (src / f"{S0}.txt").write_text("b")
    assert _replay(src).identity() != first
    (src / f"{S0}.txt").write_text("a")
    assert _replay(src).identity() == first
    (src / f"{S1}.html").write_text(HTML_PROGRAM)
    assert _replay(src).identity() != first


def test_replay_missing_source_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="does not exist"):
        _replay(tmp_path / "nowhere").check_ready()


def test_replay_missing_source_on_the_command_line_is_one_line(tmp_path, tiny_root):
    proc = run_cli("model=replay", f"model.source={tmp_path / 'nowhere'}", "dataset=original",
                   f"dataset.root={tiny_root}", "tracking=none", "run.progress=false",
                   home=tmp_path / "home", check=False, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: model=replay: model.source=")
    assert "does not exist" in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "home" / "runs").exists() or \
        not any((tmp_path / "home" / "runs").iterdir())


# =============================================================================== replay CLI


def _rows(run_dir: Path) -> dict[str, dict]:
    rows = [json.loads(x) for x in (run_dir / "results.jsonl").read_text().splitlines()]
    return {r["scene_id"]: r for r in rows}


def _summary(run_dir: Path) -> dict:
    return json.loads((run_dir / "summary.json").read_text())


@pytest.fixture(scope="module")
def replay_runs(tmp_path_factory, tiny_root):
    """One VISPHY_HOME, four replay runs over the 4-scene tiny dataset (S3 never has a reply):
    a folder of replies in three layouts, the run directory of that run, a folder of videos,
    and the run directory of that run."""
    base = tmp_path_factory.mktemp("replay")
    home = base / "home"
    replies = base / "replies"
    replies.mkdir()
    (replies / f"{S0}.txt").write_text(reply("html"))
    (replies / f"{S1}.html").write_text(HTML_PROGRAM)
    (replies / S2).mkdir()
    (replies / S2 / "answer.md").write_text(reply("html"))
    videos = base / "videos"
    videos.mkdir()
    for sid in (S0, S1, S2):  # the ground truth itself, as a pixel-space model's output
        shutil.copyfile(tiny_root / "sub" / "videos" / f"{sid}.mp4", videos / f"{sid}.mp4")

    runs: dict[str, tuple[Path, object]] = {}

    def replay(name: str, source: Path) -> None:
        before = set((home / "runs").iterdir()) if (home / "runs").exists() else set()
        proc = run_cli("model=replay", f"model.source={source}", "dataset=original",
                       f"dataset.root={tiny_root}", "tracking=none", "run.progress=false",
                       home=home, timeout=300)
        (run_dir,) = set((home / "runs").iterdir()) - before
        runs[name] = (run_dir, proc)

    replay("folder", replies)
    replay("rundir", runs["folder"][0])
    replay("videos", videos)
    replay("video_rundir", runs["videos"][0])
    return {"home": home, "root": tiny_root, "replies_dir": replies, "videos_dir": videos,
            **runs}


@pytest.mark.browser
def test_replay_folder_run_every_scene_is_a_row(replay_runs):
    run_dir, proc = replay_runs["folder"]
    rows = _rows(run_dir)
    assert list(rows) == [S0, S1, S2, S3]
    for sid in (S0, S1, S2):
        r = rows[sid]
        assert r["model_success"] and not r["fallback"] and r["failure_class"] is None, r
        assert r["attempts"] == 1 and r["output_kind"] == "program" and r["cost_usd"] == 0
        assert r["score_psnr"] is not None and r["score_ssim"] is not None
    missing = rows[S3]
    assert not missing["model_success"] and missing["failure_class"] == "model_error"
    assert missing["first_failure_class"] == "model_error"
    assert missing["fallback"] and missing["system_success"] and missing["attempts"] == 1
    assert f"no recorded reply for {S3}" in missing["failure_detail"]
    assert str(replay_runs["replies_dir"] / f"{S3}.txt") in missing["failure_detail"]
    assert missing["score_psnr"] is not None  # the fallback clip is scored
    import pandas as pd

    table = pd.read_parquet(run_dir / "results.parquet")
    assert list(table["scene_id"]) == [S0, S1, S2, S3]
    s = _summary(run_dir)
    assert s["status"] == "finished" and s["n_scenes"] == s["n_selected"] == 4
    assert s["model_success"] == 3 and s["system_success"] == 4 and s["fallbacks"] == 1
    assert s["failures"] == {"model": {"model_error": 1}, "infra_or_data": {}}
    assert s["usage"]["generate"]["calls"] == 4 and s["usage"]["generate"]["errors"] == 1
    assert s["usage"]["generate"]["cost_usd"] == 0
    assert s["spec"] == {"valid": 2, "invalid": 0, "absent": 2}  # S1 is a bare program
    assert s["metrics"]["psnr"]["n_model_success"] == 3
    assert "model_error" in proc.stdout


@pytest.mark.browser
def test_replay_folder_run_used_each_layout(replay_runs):
    run_dir, _ = replay_runs["folder"]
    scenes = run_dir / "scenes"
    assert (scenes / S0 / "response.txt").read_text() == reply("html")
    assert (scenes / S2 / "response.txt").read_text() == reply("html")  # the sub-folder's .md
    bare = (scenes / S1 / "response.txt").read_text()
    assert bare.startswith("```html\n") and bare.rstrip().endswith("```")
    for sid in (S0, S1, S2):
        assert (scenes / sid / "program.html").read_text().strip() == HTML_PROGRAM.strip()
        assert (scenes / sid / "video.mp4").stat().st_size > 0
    assert (scenes / S0 / "spec.json").is_file() and not (scenes / S1 / "spec.json").exists()
    assert not (scenes / S3 / "program.html").exists()
    assert json.loads((scenes / S3 / "response.json").read_text())["error_kind"] == \
        "not_recorded"
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["model"]["name"] == "replay" and manifest["model"]["output"] == "program"


@pytest.mark.browser
def test_replay_references_are_the_same_for_every_run_and_never_the_reply(replay_runs):
    root = replay_runs["root"]
    for name in ("folder", "videos"):
        run_dir, _ = replay_runs[name]
        rows = _rows(run_dir)
        for sid in (S0, S1, S2, S3):
            det = json.loads((root / "sub" / "detection_json" / f"{sid}_frame_01.json")
                             .read_text())
            text = (run_dir / "scenes" / sid / "reference.txt").read_text()
            assert text == describe_detection(det) and ANALYSIS not in text
            assert rows[sid]["reference_source"] == "detection"
    # the folder run wrote them; every later run (other model output, same ground truth) hits
    assert _summary(replay_runs["folder"][0])["cache"]["reference"] == {"hits": 0, "misses": 4}
    for name in ("rundir", "videos", "video_rundir"):
        assert _summary(replay_runs[name][0])["cache"]["reference"] == {"hits": 4, "misses": 0}


KEEP = ("scene_id", "model_success", "system_success", "fallback", "attempts", "failure_class",
        "first_failure_class", "frame_digests", "flags", "spec_valid", "prompt_version",
        "output_kind")


def _kept(rows: dict[str, dict]) -> dict[str, dict]:
    return {sid: {k: v for k, v in r.items() if k in KEEP or k.startswith("score_")}
            for sid, r in rows.items()}


@pytest.mark.browser
def test_replay_of_a_run_directory_reproduces_the_replied_rows(replay_runs):
    first = _kept(_rows(replay_runs["folder"][0]))
    second = _kept(_rows(replay_runs["rundir"][0]))
    assert list(second) == [S0, S1, S2, S3]
    for sid in (S0, S1, S2):
        assert second[sid] == first[sid]
    s = _summary(replay_runs["rundir"][0])
    assert s["renders_done"] == 0 and s["cache"]["render"]["misses"] == 0
    assert s["usage"]["generate"]["cost_usd"] == 0
    assert not second[S3]["model_success"] and second[S3]["fallback"]


@pytest.mark.browser
def test_replay_of_a_run_directory_reproduces_its_model_error_row(replay_runs):
    first = _kept(_rows(replay_runs["folder"][0]))
    second = _kept(_rows(replay_runs["rundir"][0]))
    assert second[S3] == first[S3]
    assert _summary(replay_runs["rundir"][0])["failures"] == \
        _summary(replay_runs["folder"][0])["failures"]


@pytest.mark.browser
def test_replay_of_a_video_folder_keeps_each_video(replay_runs):
    run_dir, _ = replay_runs["videos"]
    rows = _rows(run_dir)
    assert list(rows) == [S0, S1, S2, S3]
    for sid in (S0, S1, S2):
        r = rows[sid]
        assert r["model_success"] and r["output_kind"] == "video" and r["attempts"] == 1
        assert r["render_wall_s"] is None and r["spec_valid"] is None
        assert r["score_psnr"] > 35 and r["score_ssim"] > 0.99  # the ground truth itself
        assert len(json.loads(r["frame_digests"])) == 17
    assert rows[S3]["failure_class"] == "model_error" and rows[S3]["fallback"]
    assert str(replay_runs["videos_dir"] / f"{S3}.mp4") in rows[S3]["failure_detail"]
    s = _summary(run_dir)
    assert s["n_scenes"] == 4 and s["model_success"] == 3 and s["renders_done"] == 0
    assert s["failures"]["model"] == {"model_error": 1}
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["model"]["output"] == "video"


@pytest.mark.browser
def test_replay_of_a_video_run_directory_keeps_its_failures(replay_runs):
    rows = _rows(replay_runs["video_rundir"][0])
    assert rows[S3]["failure_class"] == "model_error" and not rows[S3]["model_success"]
    assert _summary(replay_runs["video_rundir"][0])["model_success"] == 3


@pytest.mark.browser
def test_replay_of_a_video_run_directory_reproduces_its_scores(replay_runs):
    first = _kept(_rows(replay_runs["videos"][0]))
    second = _kept(_rows(replay_runs["video_rundir"][0]))
    for sid in (S0, S1, S2):
        assert second[sid] == first[sid]


# =============================================================================== render command


def _render(replay_runs, reply_file: Path, out: Path, *extra: str, scene: str = S0):
    return run_cli("render", str(reply_file), f"dataset.root={replay_runs['root']}",
                   "--engine", "threejs", "--scene", scene, "--dataset", "original",
                   "-o", str(out), *extra, home=replay_runs["home"], check=False, timeout=300)


@pytest.mark.browser
def test_render_one_good_reply(replay_runs, tmp_path):
    out = tmp_path / "out"
    proc = _render(replay_runs, replay_runs["replies_dir"] / f"{S0}.txt", out)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == f"{S0}: rendered"
    assert "scene spec S: valid" in lines
    result = json.loads((out / "result.json").read_text())
    assert result["model_success"] and result["failure_class"] is None
    assert result["attempts"] == 1 and not result["fallback"]
    psnr = re.search(r"^\s+psnr (\d+\.\d{4})$", proc.stdout, re.M)
    assert psnr and float(psnr.group(1)) == pytest.approx(result["score_psnr"], abs=1e-4)
    # exactly what a run scores for the same reply and scene
    run_row = _rows(replay_runs["folder"][0])[S0]
    assert result["score_psnr"] == run_row["score_psnr"]
    assert result["frame_digests"] == run_row["frame_digests"]
    for name in ("program.html", "video.mp4", "render.log", "scores.json", "response.txt",
                 "spec.json", "reference.txt"):
        assert (out / name).is_file(), name
    assert (out / "program.html").read_text().strip() == HTML_PROGRAM.strip()
    scores = json.loads((out / "scores.json").read_text())["scores"]
    assert scores["psnr"] == result["score_psnr"] and scores["ssim"] == result["score_ssim"]


@pytest.mark.browser
def test_render_one_bare_html_program(replay_runs, tmp_path):
    out = tmp_path / "out"
    proc = _render(replay_runs, replay_runs["replies_dir"] / f"{S1}.html", out, scene=S1)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[0] == f"{S1}: rendered"
    assert json.loads((out / "result.json").read_text())["spec_valid"] is None


@pytest.mark.browser
def test_render_one_reply_without_a_program_fails_in_one_line(replay_runs, tmp_path):
    no_code = tmp_path / "reply.txt"
    no_code.write_text(ANALYSIS + "\n\nI would simulate this with a physics engine.\n")
    out = tmp_path / "out"
    proc = _render(replay_runs, no_code, out)
    assert proc.returncode == 1
    failed = [line for line in proc.stdout.splitlines() if "FAILED" in line]
    assert failed == [f"{S0}: FAILED (no_code): no ```html block in the reply"]
    assert "Traceback" not in proc.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["failure_class"] == "no_code" and not result["model_success"]
    assert result["attempts"] == 1 and not result["fallback"]  # no repair call, no fallback
    assert not (out / "video.mp4").exists() and not (out / "program.html").exists()


@pytest.mark.browser
@pytest.mark.parametrize("case", ["unknown_scene", "missing_reply"])
def test_render_one_bad_input_is_one_error_line(replay_runs, tmp_path, case):
    out = tmp_path / "out"
    if case == "unknown_scene":
        proc = _render(replay_runs, replay_runs["replies_dir"] / f"{S0}.txt", out,
                       scene="task99999_000")
        needle = "task99999_000"
    else:
        proc = _render(replay_runs, tmp_path / "no_such_reply.txt", out)
        needle = "reply file not found"
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], \
        proc.stderr
    assert "Traceback" not in proc.stderr and not out.exists()


@pytest.mark.browser
def test_render_one_overrides_after_the_options(replay_runs, tmp_path):
    out = tmp_path / "out"
    proc = run_cli("render", str(replay_runs["replies_dir"] / f"{S0}.txt"), "--engine", "threejs",
                   "--scene", S0, "--dataset", "original", "-o", str(out),
                   f"dataset.root={replay_runs['root']}", "engine.timeout_s=20",
                   home=replay_runs["home"], check=False, timeout=300)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.browser
def test_render_one_two_scene_ids_is_one_error_line(replay_runs, tmp_path):
    proc = _render(replay_runs, replay_runs["replies_dir"] / f"{S0}.txt", tmp_path / "out",
                   scene=f"{S0},{S1}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("error: ")
