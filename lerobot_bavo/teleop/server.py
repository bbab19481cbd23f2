"""`bavo-teleop`: record human demonstrations from a browser, or replay a recorded input log.

    bavo-teleop --task cube_handoff --condition stage --repo-id <user>/bavo_human_cube_handoff --root DIR
        [--host 127.0.0.1] [--port 8765] [--seed 100000] [--episode-length N]
    bavo-teleop --replay DIR/meta/bavo_teleop/seed_00100000.jsonl [--repo-id ... --root OTHER_DIR]

The server (aiohttp) serves one page and one websocket. The page shows the active-camera view
(the only view a policy gets), a small third-person view, the milestones reached and the occlusion
state, and sends the operator's keyboard / gamepad / WebXR input; the simulation runs in its own
thread at the env's 25 Hz whatever the browser's frame rate, and every tick's input is logged.
Saved episodes go into a BAVO dataset with `bavo-collect`'s schema, writer and teacher cache,
marked `annotation.source` = 1 (human); `--replay` re-drives a log without a browser and
reproduces the episode bit for bit (and saves it into `--root` when given).
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import json
import logging
import os
import shlex
import signal
import struct
import sys
from pathlib import Path

from lerobot_bavo.features import ObservationSettings
from lerobot_bavo.teleop.controls import CONTROLS_HELP

STATIC = Path(__file__).parent / "static"
logger = logging.getLogger("bavo-teleop")


def _require_aiohttp():
    try:
        from aiohttp import web  # noqa: F401
    except ImportError:
        raise SystemExit("bavo-teleop needs aiohttp: pip install 'lerobot_env_bavo[teleop]' "
                         "(or pip install aiohttp)") from None


class _Client:
    """One page connection: frames are sent latest-first (a slow page skips frames, never lags)."""

    def __init__(self, ws):
        self.ws = ws
        self.pending: bytes | None = None
        self.sending = False


class TeleopServer:
    """The web front end of a `TeleopSession`."""

    def __init__(self, session):
        self.session = session
        self.clients: set[_Client] = set()
        self.last_frame: bytes | None = None
        self.last_status: str | None = None
        self.loop: asyncio.AbstractEventLoop | None = None

    def app(self):
        from aiohttp import web

        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_static("/static", STATIC)
        return app

    async def _index(self, request):
        from aiohttp import web

        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    # called from the simulation thread
    def publish(self, header: dict, images) -> None:
        if self.loop is None:
            return
        if images is None:
            payload = json.dumps(header)
        else:
            h = json.dumps(header).encode()
            payload = struct.pack("<III", len(h), len(images[0]), len(images[1])) + h + images[0] + images[1]
        self.loop.call_soon_threadsafe(self._broadcast, payload)

    def _broadcast(self, payload) -> None:
        if isinstance(payload, str):
            self.last_status = payload
        else:
            self.last_frame = payload
        for c in list(self.clients):
            self._send(c, payload)

    def _send(self, client: _Client, payload) -> None:
        if isinstance(payload, str):  # status messages are never skipped
            asyncio.ensure_future(client.ws.send_str(payload))
            return
        client.pending = payload
        if not client.sending:
            client.sending = True
            asyncio.ensure_future(self._drain(client))

    async def _drain(self, client: _Client) -> None:
        try:
            while client.pending is not None:
                data, client.pending = client.pending, None
                await client.ws.send_bytes(data)
        except (ConnectionError, RuntimeError):
            self.clients.discard(client)
        finally:
            client.sending = False

    async def _ws(self, request):
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(heartbeat=20, max_msg_size=1 << 20)
        await ws.prepare(request)
        client = _Client(ws)
        self.clients.add(client)
        await ws.send_str(json.dumps({**self.session.status(), "help": CONTROLS_HELP}))
        if self.last_frame is not None:
            self._send(client, self.last_frame)
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    data = json.loads(msg.data)
                except ValueError:
                    continue
                if data.get("type") == "input":
                    try:
                        self.session.input.update(data)
                    except (TypeError, ValueError, AttributeError):
                        logger.warning("ignored a malformed input message: %.200s", msg.data)
                elif data.get("type") == "cmd" and data.get("cmd") in ("start", "stop", "save", "discard", "rerecord"):
                    self.session.command(data["cmd"])
        finally:
            self.clients.discard(client)
        return ws

    async def serve(self, host: str, port: int) -> None:
        """Serve until SIGINT / SIGTERM, then stop the session (a save in progress completes)."""
        from aiohttp import web

        self.loop = asyncio.get_running_loop()
        self.session.start()
        await self.loop.run_in_executor(None, self.session.ready.wait)
        if self.session.error is not None:
            raise self.session.error
        runner = web.AppRunner(self.app(), handle_signals=False)
        try:
            await runner.setup()
            site = web.TCPSite(runner, host, port)
            await site.start()  # OSError when the port is taken
            bound = runner.addresses[0]
            print(f"bavo-teleop: serving http://{bound[0]}:{bound[1]}/ (dataset {self.session.root}); Ctrl+C stops",
                  flush=True)
            stop = asyncio.Event()
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.loop.add_signal_handler(sig, stop.set)
            await stop.wait()
        finally:
            print("bavo-teleop: stopping (saved episodes are kept)", flush=True)
            for c in list(self.clients):
                await c.ws.close()
            await runner.cleanup()
            await self.loop.run_in_executor(None, self.session.close)


# ====================================================================== CLI
def build_parser() -> argparse.ArgumentParser:
    from lerobot_bavo.envs.conditions import CONDITIONS

    p = argparse.ArgumentParser(
        prog="bavo-teleop", formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__.split("\n\n")[0] + "\n\n" + "\n\n".join(__doc__.split("\n\n")[1:]),
        epilog=CONTROLS_HELP + "\n\nModes: the keyboard / gamepad drive one arm at a time (position and yaw, plus the "
        "gripper; the camera arm also pitch, or look-at mode); WebXR drives all three at once. Episodes: N starts one "
        "(seeds --seed, --seed + 1, ...), it ends at success, at the step limit or with X; Enter saves, Backspace "
        "discards (nothing is written), Z re-records the same seed.")
    p.add_argument("--task", help="benchmark task, e.g. cube_handoff")
    p.add_argument("--condition", default="stage", choices=tuple(CONDITIONS), help="visibility condition")
    p.add_argument("--repo-id", help="<user>/<name> of the dataset, e.g. me/bavo_human_cube_handoff")
    p.add_argument("--root", type=Path, default=None, help="local dataset folder (default $HF_LEROBOT_HOME/<repo-id>)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default: this machine only)")
    p.add_argument("--port", type=int, default=8765, help="port (0: any free port)")
    p.add_argument("--seed", type=int, default=100_000, help="seed of the first episode (clear of eval seeds)")
    p.add_argument("--episode-length", type=int, default=None, help="control-step limit (default: the task's)")
    p.add_argument("--image-height", type=int, default=240)
    p.add_argument("--image-width", type=int, default=320)
    p.add_argument("--n-points", type=int, default=256)
    p.add_argument("--point-frame", default="base", choices=("base", "camera"))
    p.add_argument("--third-person-height", type=int, default=240, help="height of the third-person view (pixels)")
    p.add_argument("--replay", type=Path, default=None, metavar="INPUT_LOG",
                   help="re-drive a recorded input log without a browser (saved into --root when given)")
    return p


def record_digest(record) -> dict:
    """SHA-256 of the episode's arrays: equal digests = the same episode bit for bit."""
    out = {}
    for name in ("action", "state", "rgb", "point_cloud", "camera_pose", "visibility", "progress"):
        out[name] = hashlib.sha256(getattr(record, name).tobytes()).hexdigest()[:16]
    return out


def _replay(args) -> int:
    from lerobot_bavo.teleop.session import HumanDataset, read_log, replay_log

    try:
        header, ticks = read_log(args.replay)
        record, agent, header = replay_log(args.replay)
    except (ValueError, OSError) as e:
        print(f"bavo-teleop: error: {e}", file=sys.stderr)
        return 2
    summary = {"log": str(args.replay), "task": header["task"], "condition": header["condition"],
               "seed": header["seed"], "length": record.length, "success": record.success,
               "progress": record.final_progress, "recoveries": len(agent.recoveries), "digest": record_digest(record)}
    if args.root is not None or args.repo_id is not None:
        if args.repo_id is None:
            print("bavo-teleop: error: --replay with --root also needs --repo-id", file=sys.stderr)
            return 2
        ds = HumanDataset(args.repo_id, args.root, header["task"], header["condition"],
                          ObservationSettings(**header["settings"]), header["episode_length"], int(header["seed"]),
                          command="bavo-teleop " + " ".join(shlex.quote(a) for a in sys.argv[1:]))
        try:
            summary["saved"] = ds.save(record, agent.inputs)
        finally:
            ds.close()
        summary["root"] = str(ds.root)
    print(json.dumps(summary, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    os.environ.setdefault("SVT_LOG", "1")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("lerobot", "datasets", "libav", "huggingface_hub", "aiohttp.access"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    from lerobot_bavo.datasets.video_codec import quiet_libav

    quiet_libav()
    if args.replay is not None:
        return _replay(args)
    if not args.task or not args.repo_id:
        parser.error("--task and --repo-id are required (or --replay INPUT_LOG)")
    from lerobot_bavo.envs.tasks import make_task

    try:
        make_task(args.task)
    except ValueError as e:
        parser.error(f"--task: {e}")
    if "/" not in args.repo_id:
        parser.error(f"--repo-id must look like '<user>/<name>', got {args.repo_id!r}")
    _require_aiohttp()
    from lerobot_bavo.datasets.collect import CollectionError
    from lerobot_bavo.teleop.session import TeleopConfig, TeleopSession

    cfg = TeleopConfig(
        task=args.task, condition=args.condition, repo_id=args.repo_id, root=args.root, seed=args.seed,
        settings=ObservationSettings(args.image_height, args.image_width, args.n_points, args.point_frame),
        episode_length=args.episode_length, third_person_height=args.third_person_height,
        command="bavo-teleop " + " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv)))
    server = TeleopServer(None)
    session = TeleopSession(cfg, publish=server.publish)
    server.session = session
    try:
        asyncio.run(server.serve(args.host, args.port))
    except (CollectionError, ValueError, OSError) as e:
        print(f"bavo-teleop: error: {e}", file=sys.stderr)
        return 2
    print(f"bavo-teleop: {len(session.saved)} episodes saved this session into {session.root}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
