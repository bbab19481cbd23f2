"""Hostile inputs, second round (issue 29, items 4-7): checkpoints that ask for absurd sizes or carry cut-off
weights, the viewer's network exposure, grid files built to exhaust memory, and results / datasets left
half-written. Each test reproduces the fault, checks the refusal names the problem, and that nothing finished
was lost."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from test_faults import _copy, _save_checkpoint, _small_env


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return _save_checkpoint(tmp_path_factory.mktemp("ckpt") / "pretrained_model")


def _edited(checkpoint: Path, dst: Path, **changes) -> Path:
    """A copy of `checkpoint` whose config.json has `changes` applied (a value None deletes the key)."""
    out = _copy(checkpoint, dst)
    config = json.loads((out / "config.json").read_text())
    config.update(changes)
    (out / "config.json").write_text(json.dumps(config))
    return out


def _finished_run(out: Path) -> dict[str, bytes]:
    """An output folder holding a finished earlier run (what a refusal must leave untouched): name ->
    bytes."""
    out.mkdir(parents=True, exist_ok=True)
    record = {"task": "cube_handoff", "condition": "clean", "seed": 1000, "success": True, "progress": 5}
    (out / "episodes.jsonl").write_text(json.dumps(record) + "\n")
    (out / "results.json").write_text(json.dumps({"cells": {"cube_handoff/clean": {"n_episodes": 1}}}))
    (out / "results.md").write_text("| table |\n")
    return {p.name: p.read_bytes() for p in out.iterdir()}


# ----------------------------------------------------------------------------- 4. checkpoint sizes and
# weights
@pytest.mark.parametrize(
    "field, value, message",
    [
        ("num_inference_steps", 1_000_000_000, "`num_inference_steps` must be in [1, 1000], got 1000000000"),
        ("dit_hidden_dim", -8, "`dit_hidden_dim` must be in [1, 4096], got -8"),
        ("horizon", 10**7, "`horizon` must be in [1, 1000]"),
        ("n_obs_steps", 5000, "`n_obs_steps` must be in [1, 32]"),
        ("dit_num_layers", 10**6, "`dit_num_layers` must be in [1, 64]"),
        ("dit_num_heads", 0, "`dit_num_heads` must be in [1, 64], got 0"),
        (
            "point_encoder_hidden_dims",
            [16, 10**6],
            "`point_encoder_hidden_dims` must be in [1, 4096], got 1000000",
        ),
        ("points_per_step", 3_000_000, "`points_per_step` must be in [0, 16384]"),
    ],
)
def test_a_checkpoint_asking_for_absurd_sizes_is_refused_before_anything_is_built(
    checkpoint, tmp_path, monkeypatch, field, value, message
):
    """Before: num_inference_steps 1e9 hung bavo-eval past 6 GB (the sampler schedule is precomputed), a
    negative width failed deep in torch. Now the config's own check refuses it, in bavo-eval's main process,
    before any policy is built, naming config.json, the field and the bound; an earlier run in the output
    folder is untouched."""
    from lerobot_bavo.checkpoints import CheckpointMismatchError
    from lerobot_bavo.eval.cli import evaluate
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent
    from lerobot_bavo.policies.maniflow.modeling_maniflow import ManiFlowPolicy

    def built(*args, **kwargs):
        raise AssertionError(f"a policy was built from a config with {field}={value!r}")

    monkeypatch.setattr(ManiFlowPolicy, "__init__", built)  # A-FAR's policy builds through it too
    bad = _edited(checkpoint, tmp_path / "bad", **{field: value})
    out = tmp_path / "eval"
    before = _finished_run(out)
    with pytest.raises(SystemExit) as exc:
        evaluate(str(bad), ["cube_handoff"], ["clean"], 1, 1000, out)
    assert "config.json" in str(exc.value) and message in str(exc.value)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing finished lost, nothing started
    # the agent (bavo-demo, a worker) refuses it the same way
    with _small_env() as env, pytest.raises(CheckpointMismatchError, match=re.escape(message)):
        LeRobotPolicyAgent(bad, env)


def test_size_bounds_fit_the_paper_preset_and_name_the_limit():
    from lerobot.configs import FeatureType, PolicyFeature

    from lerobot_bavo.limits import MAX_STACK_SIZE, bound_problems
    from lerobot_bavo.policies import AfarConfig, ManiFlowConfig

    for preset in ("paper", "cpu", "cpu_fast"):  # every shipped size is inside the bounds
        ManiFlowConfig(preset=preset, device="cpu")
        AfarConfig(preset=preset, device="cpu")
    ManiFlowConfig(
        preset="cpu",
        device="cpu",
        num_inference_steps=1000,
        dit_hidden_dim=1536,
        dit_num_layers=24,
        dit_num_heads=16,
    )  # 2x the paper's width and depth: still allowed
    with pytest.raises(ValueError, match=r"`dit_num_layers` x `dit_hidden_dim`\^2 = 64 x 4096\^2 exceeds"):
        ManiFlowConfig(preset="cpu", device="cpu", dit_hidden_dim=4096, dit_num_layers=64, dit_num_heads=8)
    with pytest.raises(ValueError, match=r"`wqf_hidden_dim` must be in \[1, 4096\], got -64"):
        AfarConfig(preset="cpu", device="cpu", wqf_hidden_dim=-64)
    with pytest.raises(ValueError, match=r"feature 'observation.state' has shape \[50000000\]: at most"):
        ManiFlowConfig(preset="cpu", device="cpu", input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (50_000_000,))})
    assert MAX_STACK_SIZE > 12 * 768**2
    assert bound_problems({"dit_mlp_ratio": float("nan"), "n_points": True, "unrelated": -1}) == [
        "`dit_mlp_ratio` must be in [0.01, 16.0], got nan",
        "`n_points` must be an integer in [2, 16384], got True",
    ]


def test_observation_sizes_a_checkpoint_asks_the_env_for_are_bounded(tmp_path):
    """A 3 M-point cloud or a 20 000 x 20 000 image in a checkpoint's input shapes (any policy type, e.g. ACT)
    is refused where bavo-eval reads them, naming the file; the env and LeRobot's env config refuse them
    too."""
    from lerobot_bavo.checkpoints import CheckpointMismatchError, env_settings
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.envs.configs import BavoEnvConfig
    from lerobot_bavo.eval.cli import env_kwargs_for_run

    act = tmp_path / "act"
    act.mkdir()
    for inputs, message in (
        (
            {"observation.images.active": {"type": "VISUAL", "shape": [3, 20000, 20000]}},
            r"`image_height` must be in \[16, 4096\], got 20000; `image_width` must be in \[16, 4096\], got "
            r"20000",
        ),
        (
            {"observation.point_cloud": {"type": "STATE", "shape": [3_000_000 * 6]}},
            r"`n_points` must be in \[2, 16384\], got 3000000",
        ),
    ):
        (act / "config.json").write_text(json.dumps({"type": "act", "input_features": inputs}))
        with pytest.raises(
            CheckpointMismatchError,
            match="config.json asks the env for observations out of bounds: " + message,
        ):
            env_settings(act)
        with pytest.raises(SystemExit, match=message):
            env_kwargs_for_run(str(act))
    with pytest.raises(ValueError, match=r"`n_points` must be in \[2, 16384\], got 3000000"):
        BavoEnv("cube_handoff", "clean", n_points=3_000_000, render_mode=None)
    with pytest.raises(ValueError, match=r"`image_width` must be in \[16, 4096\], got 20000"):
        BavoEnvConfig(image_width=20000)
    # a config.json that is huge, or not UTF-8: named, not read whole / not a UnicodeDecodeError
    (act / "config.json").write_bytes(b'{"type": "act", "x": "' + b"a" * (2 << 20) + b'"}')
    with pytest.raises(CheckpointMismatchError, match="config.json is over 1048576 bytes"):
        env_settings(act)
    (act / "config.json").write_bytes(b'{"type": "\xff\xfe"}')
    with pytest.raises(CheckpointMismatchError, match="config.json is not UTF-8 text"):
        env_settings(act)


def test_a_truncated_model_safetensors_is_named(checkpoint, tmp_path):
    """A cut-off download: before, LeRobot's loader raised a bare SafetensorError traceback."""
    from lerobot_bavo.checkpoints import CheckpointMismatchError, check_tensor_files
    from lerobot_bavo.eval.cli import evaluate
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent

    cut = _copy(checkpoint, tmp_path / "cut")
    weights = cut / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    out = tmp_path / "eval"
    before = _finished_run(out)
    with pytest.raises(
        SystemExit, match=r"model.safetensors is truncated or not a safetensors file \(.*incomplete"
    ):
        evaluate(str(cut), ["cube_handoff"], ["clean"], 1, 1000, out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    with _small_env() as env, pytest.raises(CheckpointMismatchError, match="model.safetensors is truncated"):
        LeRobotPolicyAgent(cut, env)
    weights.unlink()
    with pytest.raises(CheckpointMismatchError, match="has no model.safetensors"):
        check_tensor_files(cut)
    check_tensor_files(checkpoint)  # the whole one passes


# ----------------------------------------------------------------------------- 5. bavo-view --web
def _listening(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/tcp*) with a socket listening on `port`."""
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as fh:
            for line in fh.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                address, hex_port = local.rsplit(":", 1)
                if state == "0A" and int(hex_port, 16) == port:
                    out.append(address)
    return out


@pytest.fixture(scope="module")
def small_rrd(tmp_path_factory) -> Path:
    import numpy as np
    import rerun as rr

    path = tmp_path_factory.mktemp("rrd") / "small.rrd"
    rec = rr.RecordingStream("bavo_view")
    rec.save(path)
    for k in range(5):
        rec.set_time("frame_index", sequence=k)
        rec.log("world/cloud", rr.Points3D(np.random.default_rng(k).random((32, 3))))
    rec.flush()
    rec.disconnect()
    return path


@pytest.mark.skipif(
    not Path("/proc/net/tcp").exists(), reason="reads the listening sockets from /proc (Linux)"
)
def test_bavo_view_web_listens_on_loopback_only_and_stops_its_server(small_rrd):
    """Before: rerun's SDK servers listened on 0.0.0.0 (the recording was readable from the network), and a
    start could hang in serve_grpc before printing the URL. Now rerun's CLI serves it bound to 127.0.0.1; the
    URL is printed once both ports accept connections; SIGTERM stops bavo-view and its server."""
    import os
    import re
    import select
    import signal
    import subprocess
    import sys
    import urllib.request

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lerobot_bavo.viz",
            "--rrd",
            str(small_rrd),
            "--web",
            "--web-port",
            "0",
            "--grpc-port",
            "0",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert select.select([proc.stdout], [], [], 120)[0], "bavo-view printed nothing within 120 s (hung?)"
        line = proc.stdout.readline()  # the URL (or nothing: it ended)
        m = re.search(r"serving the web viewer at "
                      r"http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1"
                      r"%3A(\d+)%2Fproxy \(this machine only", line)
        assert m, line + proc.stderr.read() if proc.poll() is not None else line
        web, grpc = int(m.group(1)), int(m.group(2))
        loopback = "0100007F"  # 127.0.0.1 as /proc/net/tcp writes it
        assert _listening(web) == [loopback] and _listening(grpc) == [loopback]
        page = urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10).read()
        assert b"<html" in page.lower()
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
        assert len(children) == 1
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    assert (
        not Path(f"/proc/{children[0]}").exists()
        or "zombie" in Path(f"/proc/{children[0]}/status").read_text()
    )
    assert _listening(web) == [] and _listening(grpc) == []


def test_bavo_view_web_refuses_a_taken_port_and_documents_bind(small_rrd, capsys):
    import socket

    from lerobot_bavo.viz.cli import build_parser, main
    from lerobot_bavo.viz.serve import client_host, viewer_url

    assert "--bind" in build_parser().format_help() and "0.0.0.0" in build_parser().format_help()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["--rrd", str(small_rrd), "--web", "--grpc-port", str(port), "--web-port", "0"]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err  # before: a URL to a dead server
    with pytest.raises(SystemExit):
        main(["--rrd", str(small_rrd), "--web", "--web-port", "70000"])
    assert client_host("0.0.0.0") == "127.0.0.1" and client_host("::") == "::1"
    assert viewer_url("::1", 1, 2) == "http://[::1]:1/?url=rerun%2Bhttp%3A%2F%2F%5B%3A%3A1%5D%3A2%2Fproxy"


# ----------------------------------------------------------------------------- 6. grid files
ALIAS_BOMB = """\
a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]
b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]
c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]
d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]
e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]
f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]
g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]
h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]
tasks: [*h,*h,*h,*h,*h,*h,*h,*h,*h]
methods: {expert: expert}
"""


def test_a_yaml_alias_bomb_and_other_hostile_grid_files_are_refused_quickly(tmp_path):
    """Before: the ~500-byte bomb under `tasks:` took 18 s and 2.3 GB (its repr in the error message), a
    non-UTF-8 file gave a UnicodeDecodeError traceback. Now: refused at the first anchor (line 1), before
    anything is expanded, naming the file; messages never repr more than a few dozen characters of what
    the file holds; a finished grid is untouched. (Checked by where the refusal happens, not by a clock:
    the suite runs beside trainings on 2 cores.)"""
    from lerobot_bavo.eval.cli import main
    from lerobot_bavo.eval.grid import MAX_GRID_BYTES, GridError, load_grid

    out = tmp_path / "grid_out"
    before = _finished_run(out)
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(ALIAS_BOMB)
    with pytest.raises(
        SystemExit,
        match=rf"grid file {bomb} is not valid YAML: .*anchors and aliases \(&name, \*name\) "
        "are not allowed",
    ) as exit_info:
        main(["--grid", str(bomb), "--output-dir", str(out)])
    assert "line 1, column 4" in str(exit_info.value) and len(str(exit_info.value)) < 400
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before

    def refused(name: str, data: bytes, message: str) -> str:
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(GridError, match=message) as exc:
            load_grid(path)
        assert str(path) in str(exc.value)
        return str(exc.value)

    refused(
        "alias.yaml",
        b"tasks: &t [cube_handoff]\nconditions: *t\nmethods: {expert: expert}\n",
        "anchors and aliases",
    )
    refused(
        "latin1.yaml",
        "tasks: [caf\u00e9]\n".encode("latin-1"),
        r"is not UTF-8 text \(invalid continuation byte",
    )
    refused("big.yaml", b"# padding\n" * (MAX_GRID_BYTES // 10 + 1), f"is over {MAX_GRID_BYTES} bytes")
    refused(
        "deep.yaml", b"tasks: " + b"[" * 200_000 + b"]" * 200_000 + b"\n", "cannot be read|not valid YAML"
    )
    refused("digits.yaml", b"episodes: " + b"9" * 5000 + b"\nmethods: {expert: expert}\n", "cannot be read")
    # a long (alias-free) list: the message shows a few items, not all 50 000
    names = ", ".join(f"task{i}" for i in range(50_000)).encode()
    message = refused(
        "long.yaml", b"tasks: [" + names + b"]\nmethods: {expert: expert}\n", "unknown task 'task0'"
    )
    assert len(message) < 1000
    message = refused("long_value.yaml", b"methods: {expert: " + b"x" * 500_000 + b"}\n", "checkpoint 'xxx")
    assert len(message) < 1000


# ----------------------------------------------------------------------------- 7. results and datasets
def _fake_run_job(job: dict) -> dict:
    """An instant episode (what test_faults.FAKE_EVAL's workers return): the write path is the real one."""
    return {"task": job["task"], "condition": job["condition"], "seed": job["seed"], "success": True,
            "progress": 5, "steps": 300, "padding": "x" * 200}


def test_a_full_disk_while_writing_results_leaves_the_previous_results_whole(tmp_path, monkeypatch, capsys):
    """Before: results.json was written in place, so a full disk left invalid JSON beside the previous
    results.md. Now results.json and results.md are written through temporaries and renamed together: a failed
    write ends the run with a message, leaves both previous files as they were (valid), and the re-run
    finishes them."""
    from test_faults import _fake_eval

    from lerobot_bavo.eval import cli, run

    monkeypatch.setattr(run, "run_job", _fake_run_job)
    out = tmp_path / "eval"
    base = ["--policy", "expert", "--tasks", "cube_handoff", "--conditions", "clean", "--videos", "0",
            "--output-dir", str(out)]
    cli.main(base + ["--episodes", "1"])
    before = {name: (out / name).read_bytes() for name in ("results.json", "results.md")}
    line = len(json.dumps({"task": "cube_handoff", "condition": "clean", "seed": 1001, "success": True,
                           "progress": 5, "steps": 300, "padding": "x" * 200, "wall_s": 0.0})) + 1
    # the file-size limit lets episodes.jsonl hold both records, but not the new results.json
    full = _fake_eval(0, 2 * line + 10, ["--episodes", "2", "--output-dir", str(out)])
    assert full.returncode != 0 and "Traceback" not in full.stderr
    assert "writing results.json, results.md in" in full.stderr and "(File too large)" in full.stderr
    assert "the previous files are unchanged" in full.stderr
    assert {name: (out / name).read_bytes() for name in before} == before  # whole, and still a matching pair
    assert json.loads(before["results.json"])["cells"]["cube_handoff/clean"]["n_episodes"] == 1
    assert not list(out.glob("*.tmp"))
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 2  # the finished episode is kept

    capsys.readouterr()
    cli.main(base + ["--episodes", "2"])
    assert "2 finished episodes kept, 0 to run" in capsys.readouterr().out
    assert json.loads((out / "results.json").read_text())["cells"]["cube_handoff/clean"]["n_episodes"] == 2


def test_result_files_are_written_all_or_none(tmp_path, monkeypatch):
    import os

    from lerobot_bavo.runtime.files import default_file_mode, write_files_atomic

    a, b = tmp_path / "a.json", tmp_path / "b.md"
    write_files_atomic({a: "{}", b: b"old"})
    assert a.read_text() == "{}" and b.read_bytes() == b"old"
    assert a.stat().st_mode & 0o777 == default_file_mode()  # the usual mode, not mkstemp's 0600
    real_fsync, calls = os.fsync, []

    def failing_fsync(fd):  # the second file's write fails (as ENOSPC shows at the latest on fsync)
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="No space"):
        write_files_atomic({a: '{"new": 1}', b: b"new"})
    assert (
        a.read_text() == "{}"
        and b.read_bytes() == b"old"
        and sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.md"]
    )


DS_SETTINGS = dict(image_height=48, image_width=64, n_points=32)
DS_REPO = "tester/bavo_faults"


def _collect_config(root: Path, episodes: int, **kw):
    from lerobot_bavo.datasets import schema as S
    from lerobot_bavo.datasets.collect import CollectConfig

    base = dict(
        task="cube_handoff",
        condition="stage",
        episodes=episodes,
        repo_id=DS_REPO,
        root=root,
        workers=0,
        commit_every=2,
        settings=S.ObservationSettings(**DS_SETTINGS),
        episode_length=30,
        keep_failures=True,
        progress=False,
    )
    base.update(kw)
    return CollectConfig(**base)


def _collect_args(root: Path, episodes: int) -> list[str]:
    return [
        "--task",
        "cube_handoff",
        "--condition",
        "stage",
        "--episodes",
        str(episodes),
        "--repo-id",
        DS_REPO,
        "--root",
        str(root),
        "--workers",
        "0",
        "--commit-every",
        "2",
        "--image-height",
        "48",
        "--image-width",
        "64",
        "--n-points",
        "32",
        "--episode-length",
        "30",
        "--keep-failures",
        "--no-progress",
    ]


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    """3 episodes in 2 writer sessions: episodes 0 and 1 share one data file and one mp4 (LeRobot concatenates
    the second episode's video into the first's file), episode 2 has its own."""
    from lerobot_bavo.datasets.collect import collect

    root = tmp_path_factory.mktemp("ds") / "bavo_faults"
    assert collect(_collect_config(root, 3))["episodes"] == 3
    return root


def _files(root: Path) -> dict[str, bytes]:
    """Every committed file of a dataset (data, videos, meta), relative path -> bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.parts[len(root.parts)] in ("data", "videos", "meta")}


def test_every_dataset_file_gets_the_usual_mode(dataset_root):
    """Before: the mp4 that holds two episodes (LeRobot builds it in a NamedTemporaryFile) was 0600, every
    other file 0644."""
    from lerobot_bavo.runtime.files import default_file_mode

    modes = {str(p.relative_to(dataset_root)): p.stat().st_mode & 0o777 for p in dataset_root.rglob("*")
             if p.is_file() and p.parts[len(dataset_root.parts)] in ("data", "videos", "meta")}
    assert sum(name.endswith(".mp4") for name in modes) == 2
    assert set(modes.values()) == {default_file_mode()}, modes


def test_resume_without_meta_episodes_is_refused_and_never_reaches_the_hub(
    dataset_root, tmp_path, monkeypatch, capsys
):
    """Before: LeRobot, finding no meta/episodes, fetched meta/ from the Hub repo named by --repo-id into the
    local folder. Now bavo-collect refuses before LeRobot opens the dataset, naming the folder; nothing is
    changed."""
    import huggingface_hub
    import lerobot.datasets.dataset_metadata as dataset_metadata

    from lerobot_bavo.datasets.collect import main as collect_main

    hub_calls = []

    def no_hub(*args, **kwargs):
        hub_calls.append(args)
        raise AssertionError("the Hub was contacted")

    for module in (huggingface_hub, dataset_metadata):
        monkeypatch.setattr(module, "snapshot_download", no_hub)
    monkeypatch.setattr(dataset_metadata, "get_safe_version", no_hub)
    import shutil

    root = _copy(dataset_root, tmp_path / "no_episodes")
    shutil.rmtree(root / "meta" / "episodes")
    before = _files(root)
    assert collect_main(_collect_args(root, 4)) == 2
    err = capsys.readouterr().err
    assert f"{root / 'meta' / 'episodes'} holds no episode table (3 episode(s) in meta/info.json)" in err
    assert "fetch missing metadata from the Hub" in err and "Traceback" not in err
    assert hub_calls == [] and _files(root) == before


def _corrupt_parquet_page(path: Path) -> None:
    """Overwrite the header of the first data page of one column chunk: the footer (all the old check read)
    stays valid, reading the column fails."""
    import pyarrow.parquet as pq

    meta = pq.ParquetFile(path).metadata
    column = next(meta.row_group(0).column(i) for i in range(meta.num_columns)
                  if meta.row_group(0).column(i).path_in_schema.startswith("observation.point_cloud"))
    data = bytearray(path.read_bytes())
    data[column.data_page_offset: column.data_page_offset + 24] = b"\xff" * 24
    path.write_bytes(bytes(data))
    assert pq.ParquetFile(path).metadata.num_rows == meta.num_rows  # the footer still reads


@pytest.mark.parametrize("damage", ["truncated_mp4", "corrupt_parquet"])
def test_resume_and_the_views_builder_refuse_a_damaged_committed_file(dataset_root, tmp_path, damage, capsys):
    """Before: a truncated mp4 (it still opens: LeRobot writes the index first) or a parquet file with a
    damaged page (its footer still reads) was kept by a resumed collection and copied by the views builder,
    both exit 0; training failed on it. Now both refuse, naming the file, and change nothing; with the file
    restored the collection resumes."""
    import av

    from lerobot_bavo.datasets.collect import main as collect_main
    from lerobot_bavo.datasets.views import main as views_main

    root = _copy(dataset_root, tmp_path / damage)
    if damage == "truncated_mp4":
        bad = root / "videos" / "observation.images.active" / "chunk-000" / "file-000.mp4"
        original = bad.read_bytes()
        bad.write_bytes(original[: len(original) * 3 // 4])
        with av.open(str(bad)) as c:  # what the old check did: it opens, with a video stream
            assert c.streams.video
        message = f"corrupted video file {bad}: "
    else:
        bad = root / "data" / "chunk-000" / "file-000.parquet"
        original = bad.read_bytes()
        _corrupt_parquet_page(bad)
        message = f"corrupted data file {bad}: "
    before = _files(root)
    assert collect_main(_collect_args(root, 4)) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert _files(root) == before
    with pytest.raises(SystemExit, match=re.escape(message)):
        views_main(["--root", str(root), "--view", "points", "--output-root", str(tmp_path / "view")])
    assert not (tmp_path / "view").exists()

    bad.write_bytes(original)  # restored: the collection continues, keeping the 3 episodes
    assert collect_main(_collect_args(root, 4)) == 0
    from lerobot_bavo.datasets.hub import load_bavo_dataset

    ds = load_bavo_dataset(DS_REPO, root=root)
    assert ds.meta.total_episodes == 4
    assert all((root / name).read_bytes() == data for name, data in before.items()
               if name.startswith(("data/", "videos/")) and name != str(bad.relative_to(root)))
