"""`bavo-teleop`: control mapping through IK, human episodes in BAVO datasets, bit-for-bit replay,
and the page itself driven by key presses in headless Chromium (Debian's `chromium`).

Small settings throughout (48 x 64 images, 32 points, short episodes) so the suite stays fast.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _helpers import SMALL_SETTINGS, OutputLines

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.teleop.controls import TeleopController, TickInput, motion_command

SETTINGS = SMALL_SETTINGS
REPO = "tester/bavo_human"
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


@pytest.fixture(scope="module")
def env():
    from lerobot_bavo.envs import BavoEnv

    e = BavoEnv("cube_handoff", "clean", image_height=48, image_width=64, n_points=32, render_mode=None)
    yield e
    e.close()


def _drive(env, ctl, inputs, steps=None):
    for inp in inputs:
        env.step(ctl.step(inp))
    for _ in range(steps or 0):  # no input
        env.step(ctl.step(TickInput()))


def _site(env, name):
    return env.data.site(name).xpos.copy()


# ----------------------------------------------------------------------------- control mapping
@pytest.mark.parametrize(
    "key,axis,sign", [("d", 0, 1), ("a", 0, -1), ("w", 1, 1), ("s", 1, -1), ("r", 2, 1), ("f", 2, -1)]
)
def test_each_key_moves_the_selected_arm_the_commanded_way(env, key, axis, sign):
    env.reset(seed=0)
    ctl = TeleopController.from_env(env)
    before = {s: _site(env, f"{s}_gripper_center") for s in ("left", "right")}
    _drive(env, ctl, [TickInput(taps=("1",))] + [TickInput(keys=(key,))] * 10, steps=15)
    moved = _site(env, "left_gripper_center") - before["left"]
    assert sign * moved[axis] > 0.04, moved  # 10 ticks x 6 mm, tracked by the arm
    assert np.abs(np.delete(moved, axis)).max() < 0.01, moved
    # one arm at a time
    np.testing.assert_allclose(_site(env, "right_gripper_center"), before["right"], atol=2e-3)


def test_yaw_gripper_camera_and_fine_motion(env):
    env.reset(seed=0)
    ctl = TeleopController.from_env(env)
    R0 = ctl.arms["right"].rot.copy()
    _drive(env, ctl, [TickInput(taps=("2",))] + [TickInput(keys=("q",))] * 10)
    yaw = np.arctan2(ctl.arms["right"].rot[1, 0], ctl.arms["right"].rot[0, 0]) - np.arctan2(
        R0[1, 0], R0[0, 0]
    )
    assert (yaw + np.pi) % (2 * np.pi) - np.pi == pytest.approx(10 * 0.04 * 1.0, abs=1e-6)
    assert ctl.action()[13] == 1.0
    _drive(env, ctl, [TickInput(taps=(" ",))], steps=10)
    assert ctl.action()[13] == 0.0 and env.joint_state()[13] < 0.2  # the right gripper closed
    cam0 = _site(env, "cam_camera_center")
    _drive(env, ctl, [TickInput(taps=("3",))] + [TickInput(keys=("r",))] * 8, steps=10)
    assert _site(env, "cam_camera_center")[2] - cam0[2] > 0.03
    np.testing.assert_allclose(motion_command(TickInput(keys=("w", "shift"))), [0, 0.3, 0, 0, 0])
    np.testing.assert_allclose(motion_command(TickInput(keys=("w", "s", "d"))), [1, 0, 0, 0, 0])
    # out of reach: the target stops where the arm can be (no wind-up), and comes back at once
    _drive(env, ctl, [TickInput(taps=("1",))] + [TickInput(keys=("a",))] * 200)
    far = ctl.arms["left"].pos.copy()
    _drive(env, ctl, [TickInput(keys=("d",))] * 3)
    assert ctl.arms["left"].pos[0] > far[0]


def test_look_at_mode_keeps_looking_at_the_point_under_the_image_centre(env):
    env.reset(seed=0)
    ctl = TeleopController.from_env(env)
    _drive(env, ctl, [TickInput(taps=("l",))])
    point = ctl.arms["camera"].look_at.copy()
    assert ctl.active == "camera" and abs(point[2]) < 0.1  # on the table / objects
    start = _site(env, "cam_camera_center")
    _drive(env, ctl, [TickInput(keys=("d",))] * 10 + [TickInput(keys=("q",))] * 10, steps=25)
    cam = env.data.camera("cam_active")
    assert np.linalg.norm(cam.xpos - start) > 0.05  # the viewpoint moved
    fwd = -cam.xmat.reshape(3, 3)[:, 2]
    to_point = (point - cam.xpos) / np.linalg.norm(point - cam.xpos)
    angle = np.degrees(np.arccos(np.clip(fwd @ to_point, -1, 1)))
    assert angle < 2.0, angle  # and still looks at the point
    _drive(env, ctl, [TickInput(taps=("l",))])
    assert not ctl.look_at_mode and ctl.arms["camera"].look_at is None


def test_gamepad_and_webxr_inputs(env):
    # gamepad: standard mapping, stick up is negative; dead zone; buttons as taps / held
    np.testing.assert_allclose(motion_command(TickInput(pad=(0.1, -1.0, 0.5, 0.0))), [0, 1, 0, -0.5, 0])
    env.reset(seed=0)
    ctl = TeleopController.from_env(env)
    ctl.step(TickInput(taps=("pad5",)))
    assert ctl.active == "camera"
    ctl.step(TickInput(taps=("pad4", "pad4", "pad0")))
    assert ctl.active == "left" and ctl.arms["left"].gripper == 0.0
    # WebXR: poses relative to the first XR tick; the XR frame is y-up, -z forward
    env.reset(seed=0)
    ctl = TeleopController.from_env(env)
    ident = [0, 0, 0, 0, 0, 0, 1]
    xr0 = {
        "head": [0, 1.6, 0, 0, 0, 0, 1],
        "left": [-0.2, 1.0, -0.3] + ident[3:],
        "right": [0.2, 1.0, -0.3] + ident[3:],
        "right_trigger": 1.0,
    }
    ctl.step(TickInput(xr=xr0))
    p_left, p_right, p_cam = (ctl.arms[a].pos.copy() for a in ("left", "right", "camera"))
    assert ctl.arms["right"].gripper == 0.0 and ctl.arms["left"].gripper == 1.0
    # right hand: +5 cm x, 5 cm away
    xr1 = dict(xr0, right=[0.25, 1.0, -0.35] + ident[3:], head=[0, 1.62, 0, 0, 0, 0, 1])
    ctl.step(TickInput(xr=xr1))
    np.testing.assert_allclose(ctl.arms["right"].pos - p_right, [0.05, 0.05, 0.0], atol=1e-3)
    np.testing.assert_allclose(ctl.arms["left"].pos, p_left, atol=1e-6)
    assert ctl.arms["camera"].pos[2] - p_cam[2] == pytest.approx(0.02, abs=2e-3)
    ctl.step(TickInput())  # the XR session ended: the clutch is released
    assert ctl.xr_reference is None


# ----------------------------------------------------------------------------- sessions, datasets, replay
def _wait(pred, timeout=60.0, what="condition"):
    t0 = time.time()
    while not pred():
        if time.time() - t0 > timeout:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(0.02)


def _files(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}


def test_session_saves_discards_and_replays_bit_for_bit(tmp_path):
    from lerobot.datasets.dataset_tools import merge_datasets

    from lerobot_bavo.datasets.collect import CollectConfig, collect
    from lerobot_bavo.datasets.hub import load_bavo_dataset, read_sidecar
    from lerobot_bavo.teleop.server import main as teleop_main
    from lerobot_bavo.teleop.server import record_digest
    from lerobot_bavo.teleop.session import HumanDataset, TeleopConfig, TeleopSession, replay_log

    root = tmp_path / "human"
    frames = []
    cfg = TeleopConfig("cube_handoff", "stage", REPO, root, seed=7, settings=SETTINGS, episode_length=30)
    session = TeleopSession(cfg, publish=lambda h, im: frames.append(h))
    session.start()
    session.ready.wait(60)
    assert session.state == "idle" and session.error is None
    try:
        session.command("start")
        _wait(lambda: session.state == "running", what="running")
        session.input.update({"keys": ["w"], "taps": ["3", "l"], "seq": 1})  # look-at camera move: a recovery
        time.sleep(0.3)
        session.input.update({"keys": ["d"], "taps": ["2"], "seq": 2})
        time.sleep(0.2)
        session.input.update({"keys": [], "taps": [" "], "seq": 3})  # close the right gripper
        _wait(lambda: session.state == "ended", what="episode end")
        session.command("save")
        _wait(lambda: session.state == "idle" and session.saved, what="save")
        before = _files(root)
        session.command("start")
        _wait(lambda: session.state == "running", what="second episode")
        session.input.update({"keys": ["a"], "seq": 4})
        time.sleep(0.3)
        session.command("discard")
        _wait(lambda: session.state == "idle", what="discard")
        assert _files(root) == before  # a discarded episode leaves nothing behind
        session.command("start")  # the next seed
        _wait(lambda: session.state == "running" and frames[-1].get("tick", 0) > 3, what="third episode")
        n = len(frames)
        session.command("rerecord")  # discard it and record the same seed again
        _wait(
            lambda: any(
                h.get("type") == "frame" and h["state"] == "running" and h["tick"] > 3 for h in frames[n:]
            ),
            what="re-recorded episode",
        )
        running = [h["seed"] for h in frames[:n] if h.get("type") == "frame" and h["state"] == "running"]
        again = {h["seed"] for h in frames[n:] if h.get("type") == "frame" and h["state"] == "running"}
        assert running[0] == 7 and running[-1] == 9 and again == {9}  # 8 was discarded, 9 is recorded again
        session.command("discard")
        _wait(lambda: session.state == "idle", what="discard")
        assert _files(root) == before
    finally:
        session.close()
    assert session.error is None
    frame_headers = [h for h in frames if h.get("type") == "frame" and h["state"] == "running"]
    assert any(h.get("control_hz") for h in frame_headers) and frame_headers[-1]["max_steps"] == 30

    ds = load_bavo_dataset(REPO, root=root)  # schema, teacher cache, files
    assert ds.num_episodes == 1 and len(ds) == 30
    assert set(S.TEACHER_KEYS) <= set(ds.meta.features)
    assert {int(ds.hf_dataset[i][S.ANN_SOURCE]) for i in range(30)} == {1}
    entry = read_sidecar(root)["episodes"][0]
    assert (
        entry["source"] == "human"
        and entry["seed"] == 7
        and read_sidecar(root)["settings"]["source"] == "human"
    )

    # replay the input log: the same episode, bit for bit
    log = root / entry["input_log"]
    record, agent, header = replay_log(log)
    cols = {
        k: np.stack([np.asarray(ds.hf_dataset[i][k]) for i in range(30)])
        for k in (S.ACTION, S.OBS_STATE, S.OBS_POINT_CLOUD, S.OBS_CAMERA_POSE, S.TEACHER_ZF, S.ANN_ACTIVE)
    }
    np.testing.assert_array_equal(cols[S.ACTION], record.action)
    np.testing.assert_array_equal(cols[S.OBS_STATE], record.state)
    np.testing.assert_array_equal(cols[S.OBS_POINT_CLOUD], record.point_cloud.reshape(30, -1))
    np.testing.assert_array_equal(
        cols[S.OBS_CAMERA_POSE], record.camera_pose.reshape(30, 16).astype(np.float32)
    )
    # gripper closed; a camera recovery move
    assert cols[S.ACTION][-1, 13] == 0.0 and cols[S.ANN_ACTIVE].sum() > 0
    again, _, _ = replay_log(log)
    assert record_digest(again) == record_digest(record)  # images too

    # `bavo-teleop --replay LOG --root` writes the same rows into another dataset
    assert (
        teleop_main(
            ["--replay", str(log), "--repo-id", "tester/replayed", "--root", str(tmp_path / "replayed")]
        )
        == 0
    )
    rep = load_bavo_dataset("tester/replayed", root=tmp_path / "replayed")
    for k in (S.ACTION, S.OBS_STATE, S.TEACHER_Z0, S.ANN_VISIBILITY):
        np.testing.assert_array_equal(np.stack([np.asarray(rep.hf_dataset[i][k]) for i in range(30)]),
                                      np.stack([np.asarray(ds.hf_dataset[i][k]) for i in range(30)]))

    # an episode staged (saved) but not committed when the server died is committed on the next start
    from lerobot_bavo.datasets.staging import stage_episode

    staged = replay_log(log)[0]
    staged.seed = 9
    (root / ".bavo_staging").mkdir()
    stage_episode(staged, root / ".bavo_staging", kept=True)
    reopened = HumanDataset(REPO, root, "cube_handoff", "stage", SETTINGS, 30, seed=7)
    try:
        assert len(reopened) == 2 and reopened.next_seed == 10
    finally:
        reopened.close()

    # mixes with an expert dataset through LeRobot's merge tool; expert episodes are marked 0
    expert_root = tmp_path / "expert"
    collect(
        CollectConfig(
            task="cube_handoff",
            condition="stage",
            episodes=1,
            repo_id="tester/expert",
            root=expert_root,
            workers=0,
            settings=SETTINGS,
            episode_length=30,
            keep_failures=True,
            progress=False,
        )
    )
    expert = load_bavo_dataset("tester/expert", root=expert_root)
    human = load_bavo_dataset(REPO, root=root)
    merge_datasets([expert, human], output_repo_id="tester/mixed", output_dir=tmp_path / "mixed")
    mixed = load_bavo_dataset("tester/mixed", root=tmp_path / "mixed")
    assert mixed.num_episodes == 3
    assert [int(mixed.hf_dataset[i * 30][S.ANN_SOURCE]) for i in range(3)] == [0, 1, 1]


def test_replay_rejects_a_log_that_does_not_fit(tmp_path):
    from lerobot_bavo.teleop.session import log_header, replay_log, write_log

    log = tmp_path / "short.jsonl"
    write_log(log, log_header("cube_handoff", "clean", 0, SETTINGS, 20), [{"keys": ["d"], "taps": []}] * 5)
    with pytest.raises(ValueError, match="ends after 5 ticks but the episode goes on"):
        replay_log(log)
    (tmp_path / "bad.jsonl").write_text('{"format": "other"}\n')
    with pytest.raises(ValueError, match="not a bavo-teleop input log"):
        replay_log(tmp_path / "bad.jsonl")


def test_cli_help_explains_controls_and_modes(capsys):
    from lerobot_bavo.teleop.server import main as teleop_main

    with pytest.raises(SystemExit):
        teleop_main(["--help"])
    out = capsys.readouterr().out
    for text in (
        "--replay",
        "look-at",
        "Gamepad",
        "WebXR",
        "select the left arm",
        "discard",
        "re-record",
        "25 Hz",
    ):
        assert text in out, text
    with pytest.raises(SystemExit):
        teleop_main(["--task", "cube_handoff"])
    assert "--repo-id are required" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the page in headless Chromium
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def start_server(root: Path, *extra: str) -> tuple[subprocess.Popen, str, OutputLines]:
    """`python -m lerobot_bavo.teleop` on 127.0.0.1 and a free port; returns (process, url with the run's
    token, its output so far and to come)."""
    env = dict(os.environ, SVT_LOG="1", PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "lerobot_bavo.teleop", "--task", "cube_handoff", "--condition", "stage",
         "--repo-id", REPO, "--root", str(root), "--host", "127.0.0.1", "--port", "0", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    output = OutputLines(proc)
    m = output.wait_for(r"serving (http://127\.0\.0\.1:\d+/\?token=[\w-]+)")
    return proc, m.group(1), output


def open_page(playwright, url: str, profile: Path):
    ctx = playwright.chromium.launch_persistent_context(
        str(profile),
        executable_path=CHROMIUM,
        headless=True,
        args=CHROMIUM_ARGS,
        viewport={"width": 1020, "height": 790},
    )
    page = ctx.new_page()
    page.goto(url)
    page.wait_for_function("window.bavo && window.bavo.connected && window.bavo.frames > 0", timeout=30000)
    return ctx, page


def hold(page, key: str, seconds: float) -> None:
    page.keyboard.down(key)
    time.sleep(seconds)
    page.keyboard.up(key)


def wait_until_moved(page, expr: str, axis: int, metres: float, start: float, timeout: float = 20.0) -> None:
    """Poll until coordinate `axis` of `expr` (a position, m) exceeds `start` by `metres`, or `timeout` s
    pass: on a loaded machine the 25 Hz loop slips behind the wall clock, so a fixed hold moves less."""
    deadline = time.time() + timeout
    while time.time() < deadline and page.evaluate(expr)[axis] - start <= metres:
        time.sleep(0.1)


def hold_until_moved(page, key: str, expr: str, axis: int, metres: float) -> None:
    """Hold `key` until `expr` has moved `metres` along `axis` (see `wait_until_moved`)."""
    start = page.evaluate(expr)[axis]
    page.keyboard.down(key)
    try:
        wait_until_moved(page, expr, axis, metres, start)
    finally:
        page.keyboard.up(key)


def settled(page, expr: str, tol: float = 0.002, timeout: float = 20.0) -> list[float]:
    """The value of `expr` (a position, m) once two reads 0.3 s apart differ by less than `tol` in every
    coordinate: on a loaded machine the 25 Hz loop slips behind the wall clock, so an arm can still be
    carrying out a released key's last commands when a fixed sleep ends."""
    last = page.evaluate(expr)
    deadline = time.time() + timeout
    while time.time() < deadline:
        time.sleep(0.3)
        now = page.evaluate(expr)
        if max(abs(a - b) for a, b in zip(now, last)) < tol:
            return now
        last = now
    return last


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's `chromium` (apt-get install chromium)")
def test_browser_key_presses_drive_the_arm_and_record_a_dataset(tmp_path):
    playwright_api = pytest.importorskip(
        "playwright.sync_api", reason="needs playwright (pip install playwright)"
    )
    from lerobot_bavo.datasets.hub import load_bavo_dataset, read_sidecar
    from lerobot_bavo.teleop.session import replay_log

    root = tmp_path / "human"
    proc, url, output = start_server(root, "--image-height", "48", "--image-width", "64", "--n-points", "32",
                             "--episode-length", "60", "--third-person-height", "120", "--seed", "3")
    try:
        with playwright_api.sync_playwright() as p:
            ctx, page = open_page(p, url, tmp_path / "profile")
            try:
                state = lambda s: page.wait_for_function(f"window.bavo.status.state === '{s}'", timeout=60000)  # noqa: E731
                page.keyboard.press("n")
                state("running")
                page.keyboard.press("2")  # the right arm
                page.wait_for_function("window.bavo.lastHeader && window.bavo.lastHeader.arm === 'right'")
                x0 = page.evaluate("window.bavo.lastHeader.ee.right")
                hold_until_moved(page, "d", "window.bavo.lastHeader.ee.right", axis=0, metres=0.03)  # +x
                hold_until_moved(page, "r", "window.bavo.lastHeader.ee.right", axis=2, metres=0.02)  # +z
                x1 = settled(page, "window.bavo.lastHeader.ee.right")
                assert x1[0] - x0[0] > 0.03 and x1[2] - x0[2] > 0.02 and abs(x1[1] - x0[1]) < 0.01, (x0, x1)
                state("ended")  # the 60-step limit
                before = _files(root)
                page.keyboard.press("Enter")
                page.wait_for_function(
                    "window.bavo.status.episodes === 1 && window.bavo.status.state === 'idle'", timeout=120000
                )
                assert _files(root) != before
                saved = _files(root)
                page.click("#b-start")
                state("running")
                hold(page, "a", 0.3)
                page.keyboard.press("Backspace")  # discard
                state("idle")
                assert _files(root) == saved  # the discarded episode left nothing
                latencies = page.evaluate("window.bavo.latencies")
                assert latencies, "no latency sample"
                print(f"key press -> next rendered frame: median {np.median(latencies):.0f} ms, "
                      f"max {np.max(latencies):.0f} ms over {len(latencies)} presses")
                # every press was answered by a rendered frame (how fast is scripts/teleop_latency.py's to
                # measure, not a timed assertion here)
                assert all(np.isfinite(v) and v >= 0 for v in latencies), latencies
                # what headless Chromium offers for WebXR by itself (the page then hides its "Enter VR"
                # button)
                native = page.evaluate(
                    "navigator.xr ? navigator.xr.isSessionSupported('immersive-vr') : 'no navigator.xr'"
                )
                assert native in (False, "no navigator.xr") and not page.is_visible("#b-xr")
                print(f"headless Chromium: navigator.xr immersive-vr supported = {native}")
            finally:
                ctx.close()
    finally:
        proc.send_signal(signal.SIGINT)  # interrupting the server keeps the saved episode
        output.rest(timeout=120)
        out = "".join(output.lines)
    assert proc.wait(30) == 0, out
    ds = load_bavo_dataset(REPO, root=root)
    assert ds.num_episodes == 1 and len(ds) == 60 and set(S.TEACHER_KEYS) <= set(ds.meta.features)
    assert int(ds.hf_dataset[0][S.ANN_SOURCE]) == 1 and read_sidecar(root)["complete"]
    _ = ds[10][S.OBS_IMAGE]  # the video decodes
    record, _, _ = replay_log(root / read_sidecar(root)["episodes"][0]["input_log"])
    actions = np.stack([np.asarray(ds.hf_dataset[i][S.ACTION]) for i in range(60)])
    np.testing.assert_array_equal(actions, record.action)  # the browser episode replays bit for bit
    assert record.action[-1, 7:13].tolist() != record.action[0, 7:13].tolist()


# A stand-in for a WebXR device: headless Chromium offers `navigator.xr` but no immersive-vr device and
# no built-in emulation, so this init script replaces `navigator.xr` with a minimal XR system whose
# poses the test sets. It exercises the page's WebXR code (session set-up, viewer and grip poses per
# XR frame, triggers) and everything after it; it says nothing about real headsets or Chromium's XR stack.
FAKE_XR = """
(() => {
  const state = { head: [0, 1.6, 0, 0, 0, 0, 1], left: [-0.2, 1.0, -0.3, 0, 0, 0, 1],
                  right: [0.2, 1.0, -0.3, 0, 0, 0, 1], rt: 0 };
  window.__xr = state;
  const pose = (a) => ({ transform: { position: { x: a[0], y: a[1], z: a[2] },
                                      orientation: { x: a[3], y: a[4], z: a[5], w: a[6] } } });
  class FakeSession extends EventTarget {
    constructor() {
      super();
      this.inputSources = [
        { handedness: "left", gripSpace: "left", gamepad: { buttons: [{ value: 0 }] } },
        { handedness: "right", gripSpace: "right",
          gamepad: { buttons: [{ get value() { return state.rt; } }] } }];
    }
    updateRenderState(s) { this.renderState = s; }
    async requestReferenceSpace() { return "ref"; }
    requestAnimationFrame(cb) {
      return setTimeout(() => cb(performance.now(), {
        getViewerPose: () => Object.assign(pose(state.head), { views: [{}] }),
        getPose: (space) => pose(state[space]) }), 16);
    }
    end() { this.dispatchEvent(new Event("end")); }
  }
  // and a stand-in gamepad (standard mapping) for the page's Gamepad API polling
  window.__pad = null;
  navigator.getGamepads = () => [window.__pad];
  window.XRWebGLLayer = class {
    constructor() { this.framebuffer = null; }
    getViewport() { return { x: 0, y: 0, width: 300, height: 150 }; }
  };
  Object.defineProperty(navigator, "xr", { configurable: true, value: {
    isSessionSupported: async (mode) => mode === "immersive-vr",
    requestSession: async () => new FakeSession() } });
})();
"""


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's `chromium` (apt-get install chromium)")
def test_page_webxr_and_gamepad_paths_with_stand_in_devices(tmp_path):
    playwright_api = pytest.importorskip(
        "playwright.sync_api", reason="needs playwright (pip install playwright)"
    )
    proc, url, output = start_server(
        tmp_path / "human",
        "--image-height",
        "48",
        "--image-width",
        "64",
        "--n-points",
        "32",
        "--episode-length",
        "200",
        "--third-person-height",
        "120",
    )
    try:
        with playwright_api.sync_playwright() as p:
            ctx = p.chromium.launch_persistent_context(
                str(tmp_path / "profile"), executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS
            )
            try:
                page = ctx.new_page()
                page.add_init_script(FAKE_XR)
                page.goto(url)
                page.wait_for_function("window.bavo && window.bavo.frames > 0", timeout=30000)
                page.keyboard.press("n")
                page.wait_for_function("window.bavo.status.state === 'running'", timeout=60000)
                page.click("#b-xr")
                time.sleep(0.5)
                ee0 = page.evaluate("window.bavo.lastHeader.ee")
                page.evaluate(
                    "window.__xr.head[1] += 0.05; window.__xr.right[0] += 0.06; window.__xr.rt = 1;"
                )
                time.sleep(1.2)
                h = page.evaluate("window.bavo.lastHeader")
                assert h["ee"]["camera"][2] - ee0["camera"][2] > 0.03, (ee0, h["ee"])  # head up -> camera up
                # right hand +x -> right arm +x
                assert h["ee"]["right"][0] - ee0["right"][0] > 0.04, (ee0, h["ee"])
                assert abs(h["ee"]["left"][0] - ee0["left"][0]) < 0.01 and h["grippers"]["right"] == 0.0
                webgl, drawn = page.evaluate("[window.bavo.xrWebGL, window.bavo.xrFramesDrawn || 0]")
                assert drawn > 0 or not webgl  # the headset view is drawn where WebGL exists
                print(f"WebXR stand-in: WebGL {webgl}, {drawn} headset frames drawn")
                page.click("#b-xr")  # exit VR: the keyboard drives again
                page.keyboard.press("1")
                hold_until_moved(page, "d", "window.bavo.lastHeader.ee.left", axis=0, metres=0.02)
                left = settled(page, "window.bavo.lastHeader.ee.left")
                assert left[0] - h["ee"]["left"][0] > 0.02
                # gamepad: left stick pushed up (axis 1 = -1) moves the selected arm away from the operator
                # (+y), held until the arm has moved 3 cm
                page.evaluate(
                    "window.__pad = {axes: [0, -1, 0, 0], buttons: Array.from({length: 17}, () => ({pressed: "
                    "false}))}"
                )
                wait_until_moved(page, "window.bavo.lastHeader.ee.left", axis=1, metres=0.03, start=left[1])
                page.evaluate("window.__pad = null")
                left2 = settled(page, "window.bavo.lastHeader.ee.left")
                assert left2[1] - left[1] > 0.03 and abs(left2[0] - left[0]) < 0.01, (left, left2)
            finally:
                ctx.close()
    finally:
        proc.send_signal(signal.SIGINT)
        output.rest(timeout=120)
        proc.wait(30)
