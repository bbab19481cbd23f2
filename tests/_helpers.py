"""Small helpers shared by the tests (imported as `from _helpers import ...`)."""

from __future__ import annotations

import contextlib
import importlib.util
import queue
import re
import signal
import threading
import time
from pathlib import Path

import numpy as np

from lerobot_bavo.features import ObservationSettings

REPO = Path(__file__).resolve().parent.parent
# The small observation the dataset, writer and teleop tests record (48 x 64 pixel images, 32 points): cheap
# to render and encode, and every feature keeps its shape's rank.
SMALL_SETTINGS = ObservationSettings(image_height=48, image_width=64, n_points=32)


def load_script(relative_path: str):
    """Import a repository script that is not part of the package (e.g. `scripts/results_table.py`) as a
    module, by path, so its functions can be tested."""
    path = REPO / relative_path
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def milestone_flags(**true: bool) -> dict[str, bool]:
    """The expected `evaluate()` dict: m1..m5 all False except those given as True."""
    return {f"m{i}": bool(true.get(f"m{i}", False)) for i in range(1, 6)}


class EditedScene:
    """An env reset with a seed whose MjData the test then edits by hand.

    Subclasses add task-specific setters; `evaluate` recomputes kinematics and contacts for the
    edited state, `settle` lets physics run first.
    """

    def __init__(self, env, seed: int = 0):
        self.env = env
        env.reset(seed=seed)
        self.m, self.d, self.task = env.model, env.data, env.task

    def qadr(self, joint: str) -> int:
        return int(self.m.jnt_qposadr[self.m.joint(joint).id])

    def evaluate(self) -> dict[str, bool]:
        import mujoco

        mujoco.mj_forward(self.m, self.d)
        return {k: bool(v) for k, v in self.task.evaluate(self.m, self.d).items()}

    def settle(self, n: int) -> dict[str, bool]:
        import mujoco

        for _ in range(n):
            mujoco.mj_step(self.m, self.d)
        return self.evaluate()


def lerobot_cli(name: str, module: str) -> list[str]:
    """The command of one of LeRobot's CLIs (e.g. `lerobot-train`): its script next to this interpreter, or
    `python -m module` when the venv has no script."""
    import sys
    from pathlib import Path

    exe = Path(sys.executable).with_name(name)
    return [str(exe)] if exe.exists() else [sys.executable, "-m", module]


def run_offline(cmd: list[str], tmp_path):
    """Run `cmd` in `tmp_path` as a user would, offline, one BLAS/OpenMP thread, its own HF cache; assert it
    succeeded (the failure message shows the end of its output) and return the CompletedProcess."""
    import os
    import subprocess

    env = dict(os.environ, HF_HUB_OFFLINE="1", HF_HOME=str(tmp_path / "hf"), OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1", MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


class OutputLines:
    """The stdout lines of a running process (text mode), read by a background thread so that a test never
    blocks on them for ever: `for line in proc.stdout` holds the whole test run if a server CLI hangs before
    printing its address. Start the process with `PYTHONFAULTHANDLER=1` so that the SIGABRT sent on a
    deadline prints every thread's stack into the failure message."""

    def __init__(self, proc):
        self.proc = proc
        self.lines: list[str] = []
        self._q: queue.Queue = queue.Queue()
        self._ended = False
        threading.Thread(target=self._pump, name="output-lines", daemon=True).start()

    def _pump(self):
        for line in self.proc.stdout:
            self._q.put(line)
        self._q.put(None)

    def _next(self, deadline: float) -> str | None:
        """The next line, or None once the output has ended; queue.Empty past `deadline` (monotonic s)."""
        if self._ended:
            return None
        line = self._q.get(timeout=max(0.0, deadline - time.monotonic()))
        if line is None:
            self._ended = True
        else:
            self.lines.append(line)
        return line

    def _drain(self, deadline: float) -> None:
        """Read up to the end of the output; queue.Empty past `deadline`."""
        while self._next(deadline) is not None:
            pass

    def _fail(self, what: str):
        """Abort the process (stacks printed), collect the rest of its output, fail naming `what`."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGABRT)
            try:
                self.proc.wait(30)
            except Exception:  # noqa: BLE001 - the failure below is what matters
                self.proc.kill()
        with contextlib.suppress(queue.Empty):  # what came within 10 s is enough for the message
            self._drain(time.monotonic() + 10)
        raise AssertionError(f"{what}; the process's output (stacks if it hung):\n" + "".join(self.lines))

    def wait_for(self, pattern: str, timeout: float = 300.0):
        """The match of the first line (from here on) matching the regex `pattern`; fails after `timeout`
        seconds or when the process ends first."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self._next(deadline)
            except queue.Empty:
                self._fail(f"no line matching {pattern!r} within {timeout:.0f} s")
            if line is None:  # its stdout closed: it is exiting
                self._fail(f"the process ended ({self.proc.wait(30)}) before printing {pattern!r}")
            if m := re.search(pattern, line):
                return m

    def rest(self, timeout: float = 120.0) -> str:
        """Everything printed after the last line read, up to the end of the output (the process exits)."""
        n = len(self.lines)
        try:
            self._drain(time.monotonic() + timeout)
        except queue.Empty:
            self._fail(f"the output did not end within {timeout:.0f} s")
        return "".join(self.lines[n:])


def tiny_points_view(root, repo_id: str, settings):
    """A 2-episode, 40-step Stage dataset of Cube Handoff at `root` (seeds 0, 1, kept even if they fail) and
    its `points` training view; returns the view's folder (`<root>_points`, repo id `<repo_id>_points`)."""
    from lerobot_bavo.datasets.collect import CollectConfig, collect
    from lerobot_bavo.datasets.views import make_view

    collect(CollectConfig(task="cube_handoff", condition="stage", episodes=2, repo_id=repo_id, root=root,
                          workers=0, commit_every=2, settings=settings, episode_length=40, keep_failures=True,
                          progress=False))
    make_view(root, "points")
    return root.with_name(f"{root.name}_points")


class IndependentVisibility:
    """V = N(target pixels with the occluder drawn) / N(target pixels without it), from
    segmentation renders of the real occluder geom."""

    def __init__(self, model, height, width, camera_id):
        from lerobot_bavo.sim.rendering import SceneRenderer

        self.renderer = SceneRenderer(model, height, width)  # groups 0, 1, 2 and 4 (occluder)
        self.camera_id = camera_id

    def counts(self, data, target_geoms) -> tuple[int, int]:
        ids = np.asarray(target_geoms)
        with_occ = self.renderer.render_segmentation(data, self.camera_id)
        without = self.renderer.render_segmentation(data, self.camera_id, hidden_groups=(4,))
        return int(np.isin(with_occ, ids).sum()), int(np.isin(without, ids).sum())

    def visibility(self, data, target_geoms) -> float:
        n_occ, n_no = self.counts(data, target_geoms)
        return n_occ / n_no if n_no else 0.0

    def close(self):
        self.renderer.close()
