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

Access: the server prints the page's address with a random token made at each start
(http://127.0.0.1:8765/?token=...); open that address. Requests without the token, from a page on
another site (Origin) or naming another host (Host: DNS rebinding) get HTTP 403 with the reason.
Every message from the page is checked whole (a bad one is answered with an error, nothing else
happens). When the page disconnects, held keys / gamepad / WebXR input is let go (the arms hold
still), and a running episode pauses until a page connects again: no frame is recorded without one.
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
from lerobot_bavo.teleop.access import WILDCARD_ADDRESSES, AccessPolicy, new_token
from lerobot_bavo.teleop.controls import CONTROLS_HELP
from lerobot_bavo.teleop.protocol import MAX_MESSAGE_BYTES, InputMessage, MessageError, parse_message

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
        self.bad_messages = 0


OPEN_PREFIX = "/static/"  # the page's script: Host / Origin checks only; everything else needs the token too
LOGGED_BAD_MESSAGES = 5  # per connection; the rest are counted (a broken page could send one per frame)


class TeleopServer:
    """The web front end of a `TeleopSession`.

    Access: every request passes `access.AccessPolicy` (Host, Origin, and the run's token for the
    page and the websocket) or gets HTTP 403 with the reason; `token` is made per run unless given,
    and `url` (set once listening) is the page's address with it. Input: every websocket message is
    checked whole by `protocol.parse_message` before the session sees it; a bad one is answered
    `{"type": "error", "error": ...}` and the connection goes on. Disconnects: when the page whose
    input is in effect goes away, that input is released (the arms hold still); when the last page
    goes, a running episode pauses (`TeleopSession.operator_left`).
    """

    def __init__(self, session, token: str | None = None):
        self.session = session
        self.token = token or new_token()
        self.policy: AccessPolicy | None = None
        self.url: str | None = None
        self.clients: set[_Client] = set()
        self.controlling: _Client | None = None  # the page whose input was applied last
        self.last_frame: bytes | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self._runner = None

    def app(self):
        from aiohttp import web

        @web.middleware
        async def guard(request, handler):
            return await self._guard(request, handler)

        app = web.Application(middlewares=[guard])
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_static("/static", STATIC)
        return app

    async def _guard(self, request, handler):
        """Refuse (403, with the reason) a request that fails the access policy; see `access`."""
        from aiohttp import web

        if self.policy is None:
            raise web.HTTPServiceUnavailable(text="bavo-teleop: starting\n")
        reason = self.policy.refusal(
            request.headers.get("Host"),
            request.headers.get("Origin"),
            request.query.get("token"),
            need_token=not request.path.startswith(OPEN_PREFIX),
        )
        if reason is not None:
            logger.warning(
                "refused %s %s from %s: %s", request.method, request.path[:100], request.remote, reason
            )
            raise web.HTTPForbidden(text=f"bavo-teleop: refused: {reason}\n")
        return await handler(request)

    async def _index(self, request):
        from aiohttp import web

        # no-referrer: the token in this page's address is not passed on to anything it loads
        return web.FileResponse(STATIC / "index.html",
                                headers={"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"})

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
        if not isinstance(payload, str):
            self.last_frame = payload
        for c in list(self.clients):
            self._send(c, payload)

    def _send(self, client: _Client, payload) -> None:
        if isinstance(payload, str):  # status and error messages are never skipped
            asyncio.ensure_future(self._send_text(client, payload))
            return
        client.pending = payload
        if not client.sending:
            client.sending = True
            asyncio.ensure_future(self._drain(client))

    async def _send_text(self, client: _Client, text: str) -> None:
        try:
            await client.ws.send_str(text)
        except (ConnectionError, RuntimeError):  # the page went away meanwhile
            self.clients.discard(client)

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
        from aiohttp import web

        ws = web.WebSocketResponse(heartbeat=20, max_msg_size=MAX_MESSAGE_BYTES)
        await ws.prepare(request)
        client = _Client(ws)
        self.clients.add(client)
        self.session.operator_joined()
        try:
            await ws.send_str(json.dumps({**self.session.status(), "help": CONTROLS_HELP}))
            if self.last_frame is not None:
                self._send(client, self.last_frame)
            async for msg in ws:
                error = self._apply(client, msg)
                if error is not None:
                    await ws.send_str(json.dumps({"type": "error", "error": error}))
        finally:
            self._left(client)
        return ws

    def _apply(self, client: _Client, msg) -> str | None:
        """Hand one websocket message to the session once it is known valid; else the error for the page."""
        from aiohttp import WSCloseCode, WSMsgType

        if msg.type == WSMsgType.BINARY:
            error = "binary messages are not accepted (send JSON text)"
        elif msg.type != WSMsgType.TEXT:
            if msg.type == WSMsgType.ERROR and getattr(msg.data, "code", None) == WSCloseCode.MESSAGE_TOO_BIG:
                # aiohttp closes with 1009 past max_msg_size; the page may read 1006 instead, its socket
                # reset while it is still sending, so the server says what happened
                logger.warning("a page sent a message over %d bytes: its connection was closed (1009)",
                               MAX_MESSAGE_BYTES)
            return None  # close / error frames: the loop ends by itself
        else:
            try:
                parsed = parse_message(msg.data)
            except MessageError as e:
                error = str(e)
            else:
                if isinstance(parsed, InputMessage):
                    self.session.input.update(parsed)
                    self.controlling = client
                else:
                    self.session.command(parsed.cmd)
                return None
        client.bad_messages += 1
        if client.bad_messages <= LOGGED_BAD_MESSAGES:
            logger.warning("bad message from a page (answered, ignored): %s", error)
        return error

    def _left(self, client: _Client) -> None:
        """A page disconnected: its input must not go on driving the robot."""
        self.clients.discard(client)
        if client.bad_messages > LOGGED_BAD_MESSAGES:
            logger.warning("that page sent %d bad messages in all", client.bad_messages)
        if not self.clients:
            self.controlling = None
            self.session.operator_left()  # releases the input and pauses a running episode
        elif client is self.controlling:
            self.controlling = None
            self.session.input.release()

    async def start(self, host: str, port: int) -> str:
        """Start the session and listen on host:port (0: any free port); returns the page's URL."""
        from aiohttp import web

        self.loop = asyncio.get_running_loop()
        self.session.start()
        await self.loop.run_in_executor(None, self.session.ready.wait)
        if self.session.error is not None:
            raise self.session.error
        self._runner = web.AppRunner(self.app(), handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, host, port)
        await site.start()  # OSError when the port is taken
        bound_port = self._runner.addresses[0][1]
        self.policy = AccessPolicy.for_bound(host, bound_port, self.token)
        self.url = self.policy.url(host)
        return self.url

    async def stop(self) -> None:
        """Close the pages, stop listening, stop the session (a save in progress completes)."""
        for c in list(self.clients):
            await c.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        await self.loop.run_in_executor(None, self.session.close)

    async def serve(self, host: str, port: int) -> None:
        """Serve until SIGINT / SIGTERM, then stop the session (a save in progress completes)."""
        self.loop = asyncio.get_running_loop()
        try:
            url = await self.start(host, port)
            wildcard = host.strip("[]") in WILDCARD_ADDRESSES
            where = f" (listening on {host}: from another machine, use its address)" if wildcard else ""
            print(
                f"bavo-teleop: serving {url}{where} (dataset {self.session.root}); Ctrl+C stops", flush=True
            )
            stop = asyncio.Event()
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.loop.add_signal_handler(sig, stop.set)
            await stop.wait()
        finally:
            print("bavo-teleop: stopping (saved episodes are kept)", flush=True)
            await self.stop()


# ====================================================================== CLI
def build_parser() -> argparse.ArgumentParser:
    from lerobot_bavo.envs.conditions import CONDITIONS

    p = argparse.ArgumentParser(
        prog="bavo-teleop",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__.split("\n\n")[0] + "\n\n" + "\n\n".join(__doc__.split("\n\n")[1:]),
        epilog=CONTROLS_HELP
        + "\n\nModes: the keyboard / gamepad drive one arm at a time (position and yaw, plus the "
        "gripper; the camera arm also pitch, or look-at mode); WebXR drives all three at once. Episodes: N "
        "starts one "
        "(seeds --seed, --seed + 1, ...), it ends at success, at the step limit or with X; Enter saves, "
        "Backspace "
        "discards (nothing is written), Z re-records the same seed.",
    )
    p.add_argument("--task", help="benchmark task, e.g. cube_handoff")
    p.add_argument("--condition", default="stage", choices=tuple(CONDITIONS), help="visibility condition")
    p.add_argument("--repo-id", help="<user>/<name> of the dataset, e.g. me/bavo_human_cube_handoff")
    p.add_argument(
        "--root", type=Path, default=None, help="local dataset folder (default $HF_LEROBOT_HOME/<repo-id>)"
    )
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default: this machine only; 0.0.0.0: all interfaces, still with "
        "the token and the Host / Origin checks)",
    )
    p.add_argument("--port", type=int, default=8765, help="port (0: any free port)")
    p.add_argument(
        "--seed", type=int, default=100_000, help="seed of the first episode (clear of eval seeds)"
    )
    p.add_argument(
        "--episode-length", type=int, default=None, help="control-step limit (default: the task's)"
    )
    default = ObservationSettings()  # the observation defaults, in one place
    p.add_argument("--image-height", type=int, default=default.image_height)
    p.add_argument("--image-width", type=int, default=default.image_width)
    p.add_argument("--n-points", type=int, default=default.n_points)
    p.add_argument("--point-frame", default="base", choices=("base", "camera"))
    p.add_argument(
        "--third-person-height", type=int, default=240, help="height of the third-person view (pixels)"
    )
    p.add_argument("--replay", type=Path, default=None, metavar="INPUT_LOG",
                   help="re-drive a recorded input log without a browser (saved into a dataset when "
                   "--repo-id is given, at --root if given too; --root alone is refused)")
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
    summary = {
        "log": str(args.replay),
        "task": header["task"],
        "condition": header["condition"],
        "seed": header["seed"],
        "length": record.length,
        "success": record.success,
        "progress": record.final_progress,
        "recoveries": len(agent.recoveries),
        "digest": record_digest(record),
    }
    if args.root is not None or args.repo_id is not None:
        if args.repo_id is None:
            print("bavo-teleop: error: --replay with --root also needs --repo-id", file=sys.stderr)
            return 2
        ds = HumanDataset(
            args.repo_id,
            args.root,
            header["task"],
            header["condition"],
            ObservationSettings(**header["settings"]),
            header["episode_length"],
            int(header["seed"]),
            command="bavo-teleop " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
        )
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
