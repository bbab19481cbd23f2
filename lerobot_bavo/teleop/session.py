"""A teleoperation session: the human operator as an agent of `EpisodeRecorder`, input logs, replay,
and the dataset writing shared with `bavo-collect`.

- `HumanAgent` has the scripted expert's interface (`reset`, `act`, `recovering`), so the recorder that
  `bavo-collect` uses records a human episode with exactly the same columns and privileged state.
  Each `act` publishes the frame the operator sees, waits for the next 25 Hz tick, reads that
  tick's input, maps it to an action (`controls.TeleopController`) and logs the input.
- Saving goes through `staging.stage_episode` (teacher cache) and `DatasetSession.commit` (one LeRobot
  writer session per episode, snapshot + rollback), so a saved episode survives any interruption
  of the server; the episode's input log is written to `meta/bavo_teleop/` first.
- `replay_log` re-drives a logged episode without a browser: same env, same seed, same inputs,
  hence the same episode bit for bit.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.features import ObservationSettings
from lerobot_bavo.sim import constants as C
from lerobot_bavo.teleop.controls import TeleopController, TickInput
from lerobot_bavo.teleop.protocol import MAX_KEYS, UNSET, InputMessage, parse_input

logger = logging.getLogger("bavo-teleop")

LOG_FORMAT = "bavo-teleop-input"
LOG_VERSION = 1
LOG_DIR = Path("meta") / "bavo_teleop"  # inside the dataset: one input log per saved episode


class EpisodeAborted(Exception):
    """The operator discarded (or asked to re-record) the running episode, or the server is stopping."""

    def __init__(self, command: str):
        super().__init__(command)
        self.command = command


# ====================================================================== the operator as an agent
class HumanAgent:
    """A human operator driving the env, for `EpisodeRecorder.record(seed, agent=...)`.

    Args:
        env: the recorder's `BavoEnv`.
        next_input: called once per control tick; returns that tick's `TickInput` (live: waits
            for the tick's deadline; replay: the next logged input). May raise `EpisodeAborted`.
        on_frame: called with (obs, info, agent) before each tick, to show the operator the frame.
        on_error: called with a message when mapping a tick's input to an action failed.

    A tick whose input the controller fails on (a bug, or an input the checks let through) holds
    the arms at the previous tick's targets instead of ending the episode: the operator keeps the
    episode recorded so far. The fallback is deterministic, so a replay of the log (which has the
    tick's input) takes the same path and stays bit for bit.

    Recovery annotation (`annotation.occlusion_active`): after an occlusion event starts, frames
    whose action moves the camera arm are marked as recovery, until the operator next moves a
    manipulator; `recoveries` lists the events the operator answered with a camera move.
    """

    source = "human"

    def __init__(self, env, next_input, on_frame=None, on_error=None):
        self.env = env.unwrapped
        self.next_input = next_input
        self.on_frame = on_frame
        self.on_error = on_error
        self.inputs: list[dict] = []
        self.failed_ticks: list[int] = []

    @property
    def recovering(self) -> bool:
        """Whether the last action was a view-recovery move (the recorder's `annotation.occlusion_active`)."""
        return self.phase == "recover_view"

    def reset(self) -> None:
        self.controller = TeleopController.from_env(self.env)
        self.phase = "start"
        self.stop_requested = False
        self.recoveries: list[dict] = []
        self.inputs = []
        self.failed_ticks = []
        self.last_seq = 0
        self._open_event: int | None = None
        self._answered = -1

    def act(self, obs=None, info=None) -> np.ndarray:
        if self.on_frame is not None:
            self.on_frame(obs, info, self)
        inp = self.next_input()
        self.last_seq = inp.seq
        self.inputs.append(inp.to_json())
        before = self.controller.action()
        try:
            action = self.controller.step(inp)
        except Exception as e:  # noqa: BLE001 - any failure here must not end the episode (see the class doc)
            tick = len(self.inputs) - 1
            # report a run of failures once
            first = not self.failed_ticks or self.failed_ticks[-1] != tick - 1
            self.failed_ticks.append(tick)
            action = before
            if first:
                logger.exception("tick %d: the controller failed on this input; the arms hold still", tick)
                if self.on_error is not None:
                    self.on_error(f"tick {tick}: the input could not be applied ({type(e).__name__}: {e}); "
                                  "the arms hold still while it lasts")
        occ = (info or {}).get("occlusion")
        if occ is not None and occ.get("event_started"):
            self._open_event = int(occ["event"]["index"])
        manip = np.any(action[: C.CAMERA_ARM.start] != before[: C.CAMERA_ARM.start])
        if self._open_event is not None and self.controller.camera_moved and not manip:
            self.phase = "recover_view"
            if self._answered != self._open_event:
                self._answered = self._open_event
                self.recoveries.append({"event": self._open_event, "step": int(info["elapsed_steps"])})
        else:
            self.phase = "manipulate"
            if manip:
                self._open_event = None
        self.stop_requested = inp.stop
        return action


# ====================================================================== input logs
def log_header(
    task: str, condition: str, seed: int, settings: ObservationSettings, episode_length: int | None
) -> dict:
    return {
        "format": LOG_FORMAT,
        "version": LOG_VERSION,
        "task": task,
        "condition": condition,
        "seed": int(seed),
        "settings": settings.to_dict(),
        "episode_length": episode_length,
        "fps": S.FPS,
    }


def write_log(path: Path, header: dict, inputs: list[dict]) -> None:
    """One JSON object per line: the header, then one input per control tick (atomic rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(json.dumps(header) + "\n")
        for k, inp in enumerate(inputs):
            f.write(json.dumps({"tick": k, **inp}) + "\n")
    tmp.replace(path)


def read_log(path: str | Path) -> tuple[dict, list[TickInput]]:
    lines = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    if not lines or lines[0].get("format") != LOG_FORMAT:
        raise ValueError(
            f"{path} is not a bavo-teleop input log (its first line must be a {LOG_FORMAT!r} header)"
        )
    if lines[0].get("version") != LOG_VERSION:
        raise ValueError(
            f"{path}: input log version {lines[0].get('version')}, this bavo-teleop reads {LOG_VERSION}"
        )
    ticks = [TickInput.from_json(d) for d in lines[1:]]
    if [d.get("tick") for d in lines[1:]] != list(range(len(ticks))):
        raise ValueError(f"{path}: ticks are not numbered 0..{len(ticks) - 1} (truncated or edited log)")
    return lines[0], ticks


def replay_log(path: str | Path, recorder=None):
    """Re-drive a logged episode without a browser; returns (EpisodeRecord, HumanAgent, header).

    Raises ValueError when the log does not fit the episode (it ends early, or goes on after the env ended).
    """
    from lerobot_bavo.datasets.recording import EpisodeRecorder

    header, ticks = read_log(path)
    settings = ObservationSettings(**header["settings"])
    own = recorder is None
    if own:
        recorder = EpisodeRecorder(header["task"], header["condition"], settings, header["episode_length"])
    it = iter(ticks)

    def next_input() -> TickInput:
        try:
            return next(it)
        except StopIteration:
            raise ValueError(
                f"{path}: the log ends after {len(ticks)} ticks but the episode goes on"
            ) from None

    agent = HumanAgent(recorder.env, next_input)
    try:
        record = recorder.record(int(header["seed"]), agent=agent)
    finally:
        if own:
            recorder.close()
    if record.length != len(ticks):
        raise ValueError(f"{path}: the episode ended after {record.length} ticks, the log has {len(ticks)}")
    return record, agent, header


# ====================================================================== live input (browser -> sim thread)
class LiveInput:
    """Input state shared between the web server (writer) and the control loop (reader).

    The page sends the keys it holds, edge events (taps), the gamepad axes and WebXR poses; the
    control loop takes one snapshot per tick at a fixed 25 Hz deadline, whatever the page's rate.
    Only validated messages (`protocol.parse_input`) are applied, and taps waiting for the next
    tick are capped at MAX_PENDING_TAPS (the oldest are dropped): no one can make the state, or
    the per-tick log entry it becomes, large.
    """

    MAX_PENDING_TAPS = MAX_KEYS

    def __init__(self):
        self._lock = threading.Lock()
        self.keys: set[str] = set()
        self.taps: list[str] = []
        self.pad: tuple[float, ...] | None = None
        self.xr: dict | None = None
        self.seq = 0
        self.stop = False

    def update(self, msg: InputMessage | dict) -> None:
        """Apply one input message (a dict is validated first: `MessageError` if it is not valid)."""
        if not isinstance(msg, InputMessage):
            msg = parse_input(msg)
        with self._lock:
            if msg.keys is not UNSET:
                self.keys = set(msg.keys)
            if msg.taps:
                self.taps = (self.taps + list(msg.taps))[-self.MAX_PENDING_TAPS:]
            if msg.pad is not UNSET:
                self.pad = msg.pad
            if msg.xr is not UNSET:
                self.xr = msg.xr
            self.seq = max(self.seq, msg.seq)

    def release(self) -> None:
        """Let go of everything held (keys, gamepad, WebXR) and pending taps: the arms hold still.

        Called when the operator's page disconnects, so no input outlives the client that sent it.
        The sequence number restarts too: the next page counts from 1 (it only measures latency).
        """
        with self._lock:
            self.taps, self.seq = [], 0
            self.keys, self.pad, self.xr = set(), None, None

    def clear(self) -> None:
        with self._lock:
            self.taps, self.stop = [], False
            self.keys, self.pad, self.xr = set(), None, None

    def snapshot(self) -> TickInput:
        with self._lock:
            inp = TickInput(keys=tuple(sorted(self.keys)), taps=tuple(self.taps), pad=self.pad, xr=self.xr,
                            seq=self.seq, stop=self.stop)
            self.taps, self.stop = [], False
        return inp


# ====================================================================== the dataset
class HumanDataset:
    """A BAVO dataset that human episodes are saved into, through `bavo-collect`'s own machinery.

    Opening it takes `bavo-collect`'s lock on the folder, creates or checks the dataset (same schema,
    same settings check), rolls back a commit interrupted by a kill and commits episodes that were
    staged but not committed. `save()` writes the input log, stages the episode with its teacher cache
    (`staging.stage_episode`) and commits it in its own LeRobot writer session (`DatasetSession.commit`).
    """

    def __init__(
        self,
        repo_id: str,
        root: Path | None,
        task: str,
        condition: str,
        settings: ObservationSettings,
        episode_length: int | None,
        seed: int,
        command: str | None = None,
    ):
        from lerobot_bavo.datasets.collect_config import CollectConfig
        from lerobot_bavo.datasets.session import DatasetSession

        self.task, self.condition, self.settings, self.episode_length = (
            task,
            condition,
            settings,
            episode_length,
        )
        ccfg = CollectConfig(
            task=task,
            condition=condition,
            episodes=1,
            repo_id=repo_id,
            root=root,
            workers=0,
            seed=seed,
            commit_every=1,
            settings=settings,
            episode_length=episode_length,
            keep_failures=True,
            progress=False,
            command=command,
        )
        self.session = DatasetSession(ccfg)
        self.session.settings["source"] = "human"  # recorded; with keep_failures it keeps expert runs out
        self.root = self.session.root
        self._lock = self.session.lock()
        try:
            self.session.open()
            staged = self.session.scan_staging(self.session.record.next_seed)
            for seed_, summary in sorted(staged.items()):
                if summary.get("kept"):  # saved, then the server was killed before the commit ended
                    logger.warning("committing episode seed %d, saved before an interruption", seed_)
                    self._commit(summary)
        except BaseException:
            self._lock.close()
            raise

    @property
    def record(self):
        """The dataset's `CollectionRecord`."""
        return self.session.record

    @property
    def next_seed(self) -> int:
        return self.session.record.next_seed

    def __len__(self) -> int:
        return len(self.session.record.episodes)

    def save(self, record, inputs: list[dict]) -> dict:
        """Append one recorded episode (and its input log); returns its entry in the collection record."""
        from lerobot_bavo.datasets.staging import stage_episode

        seed = int(record.seed)
        if seed < self.next_seed:
            raise ValueError(f"seed {seed} is below the dataset's next seed {self.next_seed}: already used")
        write_log(self.root / LOG_DIR / f"seed_{seed:08d}.jsonl",
                  log_header(self.task, self.condition, seed, self.settings, self.episode_length), inputs)
        summary = stage_episode(record, self.session.staging, kept=True)
        return self._commit(summary)

    def _commit(self, summary: dict) -> dict:
        col = self.session
        seed = int(summary["seed"])
        col.commit([summary], [], max(col.record.next_seed, seed + 1))  # rolls itself back if interrupted
        entry = col.record.episodes[-1]
        entry.update(source="human", success=bool(summary["success"]), progress=int(summary["progress"]),
                     input_log=str(LOG_DIR / f"seed_{seed:08d}.jsonl"))
        col.save_record()
        return entry

    def close(self) -> None:
        """Per-channel point-cloud statistics, the collection record and the dataset card; releases the
        lock."""
        if self._lock is None:
            return
        col = self.session
        try:
            n = len(self)
            if n == 0:  # nothing saved: an empty dataset (statistics need data)
                import shutil

                shutil.rmtree(col.staging, ignore_errors=True)
                return
            col.cfg.episodes = n
            col.finish({"started": time.strftime("%Y-%m-%d %H:%M:%S"), "requested": n, "committed_before": n,
                         "workers": 0, "attempts": 0, "reused_staged": 0, "tool": "bavo-teleop"}, 0.0)
        finally:
            self._lock.close()
            self._lock = None


# ====================================================================== the session
@dataclass
class TeleopConfig:
    """Arguments of a teleoperation session (the CLI's flags); see `bavo-teleop --help`."""

    task: str
    condition: str
    repo_id: str
    root: Path | None = None
    seed: int = 100_000
    settings: ObservationSettings = field(default_factory=ObservationSettings)
    episode_length: int | None = None
    third_person_height: int = 240
    jpeg_quality: int = 80
    command: str | None = None


class TeleopSession:
    """Owns the recorder, the dataset writer and the control loop; runs in its own thread (`start()`).

    Commands (`command(name)`): start, stop, save, discard, rerecord, quit. `publish(header, jpegs)`
    is called with every frame and status change, and with `{"type": "error", ...}` (no images)
    when something failed that the operator should know about.

    The web server calls `operator_left()` when the last page disconnects: held input is released
    and a running episode pauses (no tick is simulated or recorded) until `operator_joined()`. So
    no frame is ever recorded from input whose sender is gone. Without a server (tests, scripts),
    the operator counts as present.

    The loop survives failures: a failing tick holds the arms still (`HumanAgent`), a failing
    command (a save, say) is logged and reported, and an episode that ended but is not saved stays
    pending, so the operator can save it again or discard it.
    """

    def __init__(self, cfg: TeleopConfig, publish=None):
        self.cfg = cfg
        self.publish = publish or (lambda header, images: None)
        self.input = LiveInput()
        self.commands: queue.Queue[str] = queue.Queue()
        self.state = "starting"
        self.message = ""
        self.pending = None  # (EpisodeRecord, inputs) of an ended episode, not yet saved or discarded
        self.saved: list[dict] = []
        self.error: BaseException | None = None
        self.ready = threading.Event()
        self.operator_present = threading.Event()
        self.operator_present.set()
        self._frame_failed = False
        self._thread: threading.Thread | None = None
        self._tick_deadline = 0.0
        self._tick_times: list[float] = []
        self.overruns = 0

    # ---------------------------------------------------------------- thread control
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="bavo-teleop-sim", daemon=True)
        self._thread.start()

    def command(self, name: str) -> None:
        self.commands.put(name)

    @property
    def agent(self) -> HumanAgent | None:
        """The operator's agent of the episode running (or last run); None before the first."""
        return getattr(self, "_agent", None)

    def is_alive(self) -> bool:
        """Whether the simulation thread runs (it ends only at `close()` or when opening failed)."""
        return self._thread is not None and self._thread.is_alive()

    def operator_left(self) -> None:
        """No page is connected any more: let go of the held input and pause a running episode."""
        self.input.release()
        self.operator_present.clear()

    def operator_joined(self) -> None:
        """A page is connected: a paused episode goes on."""
        self.operator_present.set()

    def report_error(self, text: str) -> None:
        """Tell the pages that something failed (`{"type": "error", "error": text}`)."""
        self.publish({"type": "error", "error": text}, None)

    def close(self, timeout: float = 600.0) -> None:
        """Stop the loop: a running episode is dropped, a save in progress completes; then finish the
        dataset."""
        self.commands.put("quit")
        if self._thread is not None:
            self._thread.join(timeout)

    # ---------------------------------------------------------------- sim thread
    def _run(self) -> None:
        try:
            self._open()
            self.ready.set()
            self._loop()
        except BaseException as e:  # reported to the page and re-raised by the server
            logger.exception("teleoperation loop failed")
            self.error = e
            self.state, self.message = "error", f"{type(e).__name__}: {e}"
            self._status()
        finally:
            self.ready.set()
            self._finish()

    def _open(self) -> None:
        from lerobot_bavo.datasets.recording import EpisodeRecorder
        from lerobot_bavo.sim.rendering import SceneRenderer

        cfg = self.cfg
        self.dataset = HumanDataset(
            cfg.repo_id,
            cfg.root,
            cfg.task,
            cfg.condition,
            cfg.settings,
            cfg.episode_length,
            cfg.seed,
            cfg.command,
        )
        self.root = self.dataset.root
        self.next_seed = self.dataset.next_seed
        self.recorder = EpisodeRecorder(cfg.task, cfg.condition, cfg.settings, cfg.episode_length)
        h = cfg.third_person_height
        self._third = SceneRenderer(self.recorder.env.model, h, 4 * h // 3)
        self.state, self.message = "idle", "press N (or Start) to begin an episode"
        self._show_reset(self.next_seed)

    def _loop(self) -> None:
        while True:
            cmd = self.commands.get()
            if cmd == "quit":
                return
            try:
                if self._handle(cmd) == "quit":
                    return
            except Exception as e:  # noqa: BLE001 - the loop must go on (see the class doc)
                logger.exception("command %r failed", cmd)
                kept = self.pending is not None
                self.state = "ended" if kept else "idle"
                self.message = f"{cmd} failed ({type(e).__name__}: {e})" + (
                    "; the episode is kept: Enter saves it, Backspace discards it" if kept else ""
                )
                self.report_error(self.message)
                self._status()

    def _handle(self, cmd: str) -> str | None:
        """One command between episodes; "quit" when the server is stopping during an episode."""
        if cmd in ("start", "rerecord"):
            if self.pending is not None and cmd == "start":
                self.message = "save (Enter) or discard (Backspace) the last episode first"
                self._status()
                return None
            if cmd == "rerecord" and self.pending is not None:
                self.pending = None
            elif cmd == "start" and self.state == "idle" and self._last_seed_done:
                self.next_seed += 1
            return self._episode(self.next_seed)
        if cmd == "save" and self.pending is not None:
            self._save()
        elif cmd == "discard" and self.pending is not None:
            self.pending = None
            self._last_seed_done = True
            self.state, self.message = "idle", "episode discarded; N starts the next seed"
            self._show_reset(self.next_seed + 1)
        return None

    _last_seed_done = False

    def _episode(self, seed: int) -> str | None:
        self.input.clear()
        self.state, self.message = "running", f"episode seed {seed}"
        self._tick_deadline = time.perf_counter()
        self._tick_times = []
        agent = HumanAgent(
            self.recorder.env, self._next_input, self._on_tick_frame, on_error=self.report_error
        )
        self._agent = agent
        self._frame_failed = False
        t0 = time.time()
        try:
            record = self.recorder.record(seed, agent=agent)
        except EpisodeAborted as e:
            if e.command == "quit":
                return "quit"
            if e.command == "rerecord":
                self.commands.put("rerecord")
                self.message = f"re-recording seed {seed}"
            else:
                self._last_seed_done = True
                self.message = "episode discarded; N starts the next seed"
            self.state = "idle"
            self._show_reset(seed if e.command == "rerecord" else seed + 1)
            return None
        self.pending = (record, list(agent.inputs), t0)
        self._last_seed_done = False
        end = "success" if record.success else ("stopped" if agent.stop_requested else "step limit")
        self.state = "ended"
        self.message = (
            f"episode ended ({end}, {record.length} steps): Enter saves, Backspace discards, Z re-records"
        )
        self._on_frame(None, None, agent, final=True)
        if self._after_end_save:
            self._after_end_save = False
            self._save()
        return None

    _after_end_save = False

    def _next_input(self) -> TickInput:
        """Wait for this tick's deadline (fixed 25 Hz), handle page commands, return the input snapshot.

        With no page connected, first wait for one (`_pause`): the tick is taken when someone can see it.
        """
        stop = self._pause() if not self.operator_present.is_set() else False
        now = time.perf_counter()
        if now < self._tick_deadline:
            time.sleep(self._tick_deadline - now)
        else:
            self.overruns += now - self._tick_deadline > 0.005
        self._tick_times.append(time.perf_counter())
        self._tick_deadline = max(self._tick_deadline + C.CONTROL_DT, time.perf_counter() - C.CONTROL_DT)
        stop = self._episode_commands() or stop
        inp = self.input.snapshot()
        if stop:
            inp.stop = True
        return inp

    def _episode_commands(self) -> bool:
        """Commands that came in during the episode: True to end it at this tick (stop, or save);
        raises `EpisodeAborted` for discard, rerecord and quit."""
        stop = False
        while True:
            try:
                cmd = self.commands.get_nowait()
            except queue.Empty:
                return stop
            if cmd in ("discard", "rerecord", "quit"):
                raise EpisodeAborted(cmd)
            if cmd == "stop":
                stop = True
            elif cmd == "save":  # Enter while running: end the episode here and save it
                stop = True
                self._after_end_save = True

    def _pause(self) -> bool:
        """Hold the running episode, simulating and recording nothing, until a page connects again.

        Commands are still handled (the server's quit, above all); returns whether one asked to
        end the episode. The 25 Hz clock restarts afterwards, so no ticks are made up in a burst.
        """
        state, message = self.state, self.message
        self.state, self.message = "paused", "paused: no page is connected (open the page again to go on)"
        logger.info("no page connected: episode paused")
        self._status()
        stop = False
        while not self.operator_present.wait(0.05):
            stop = self._episode_commands() or stop
        self.state, self.message = state, message
        logger.info("a page connected: episode resumed")
        self._status()
        self._tick_deadline = time.perf_counter()
        self._tick_times = []
        return stop

    def _on_tick_frame(self, obs, info, agent) -> None:
        """`_on_frame` during an episode: a frame that cannot be shown must not end the recording."""
        try:
            self._on_frame(obs, info, agent)
        except Exception as e:  # noqa: BLE001
            if not self._frame_failed:  # once per episode: the same failure would repeat every tick
                logger.exception("showing the frame failed (the episode goes on)")
                self.report_error(f"showing the frame failed ({type(e).__name__}: {e}); the episode goes on")
            self._frame_failed = True

    def _save(self) -> None:
        record, inputs, _ = self.pending
        self.state, self.message = "saving", f"saving episode seed {record.seed} ({record.length} frames)..."
        self._status()
        self.saved.append(self.dataset.save(record, inputs))
        self.pending = None
        self._last_seed_done = True
        n = len(self.dataset)
        self.state, self.message = (
            "idle",
            f"saved as episode {n - 1} ({n} in the dataset); N starts the next seed",
        )
        self._show_reset(self.next_seed + 1)

    def _finish(self) -> None:
        try:
            if getattr(self, "dataset", None) is not None:
                self.dataset.close()
        except Exception:
            logger.exception("finishing the dataset failed (saved episodes are committed)")
        finally:
            for r in (getattr(self, "_third", None), getattr(self, "recorder", None)):
                if r is not None:
                    r.close()
            self.state = "closed"

    # ---------------------------------------------------------------- frames and status
    def _show_reset(self, seed: int) -> None:
        env = self.recorder.env
        obs, info = env.reset(seed=seed)
        self._agent = None
        self._on_frame(obs, info, None, final=True)

    def status(self) -> dict:
        return {"type": "status", "state": self.state, "message": self.message, "task": self.cfg.task,
                "condition": self.cfg.condition, "seed": getattr(self, "next_seed", None),
                "episodes": len(self.dataset) if getattr(self, "dataset", None) is not None else 0}

    def _status(self) -> None:
        self.publish(self.status(), None)

    def _on_frame(self, obs, info, agent, final: bool = False) -> None:
        env = self.recorder.env
        if obs is None:
            obs = {"pixels": {"active": env.render_active_rgb()}}
            info = env.current_info()
        header = self.status()
        header["type"] = "frame"
        if agent is not None:
            ctl = agent.controller
            header.update(ack=agent.last_seq, arm=ctl.active, look_at=ctl.look_at_mode,
                          grippers={s: round(float(ctl.arms[s].gripper), 3) for s in ("left", "right")},
                          recovering=agent.phase == "recover_view")
        header["tick"] = int(info.get("elapsed_steps", 0)) if info else 0
        header["progress"] = int(info.get("progress", 0)) if info else 0
        header["milestones"] = {k: bool(v) for k, v in (info.get("milestones") or {}).items()} if info else {}
        occ = info.get("occlusion") if info else None
        header["occlusion"] = None if occ is None else {
            "event": int(occ["event"]["index"]), "events": int(occ["num_events"]), "target": occ["target"],
            "visibility": None if occ["visibility"] is None else round(float(occ["visibility"]), 3),
            "started": bool(occ["event_started"])}
        header["ee"] = {name: [round(float(v), 4) for v in env.data.site(site).xpos]
                        for name, site in (("left", "left_gripper_center"), ("right", "right_gripper_center"),
                                           ("camera", "cam_camera_center"))}
        if len(self._tick_times) > 1:
            window = self._tick_times[-26:]
            header["control_hz"] = round((len(window) - 1) / max(window[-1] - window[0], 1e-6), 1)
        header["overruns"] = int(self.overruns)
        header["max_steps"] = int(env.max_episode_steps)
        third = self._third.render_rgb(env.data, C.THIRD_PERSON_CAMERA)
        self.publish(
            header,
            (_jpeg(obs["pixels"]["active"], self.cfg.jpeg_quality), _jpeg(third, self.cfg.jpeg_quality)),
        )


def _jpeg(rgb: np.ndarray, quality: int) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()
