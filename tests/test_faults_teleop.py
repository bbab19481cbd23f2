"""Fault tests of `bavo-teleop` (issue 29): requests from other sites, bad input messages, a page that
goes away while keys are held, and failures inside the simulation thread.

Each fault is played against a real server: `TeleopServer` with a real `TeleopSession` (dataset,
recorder, renderer), listening on 127.0.0.1 and an ephemeral port, on its own event loop in a
background thread; the tests talk to it over real HTTP / websocket connections (aiohttp's client).
After each fault the test checks what the client was told, that the service still works (a valid
command goes through) and that nothing recorded was lost. The pure checks (`protocol.parse_message`,
`access.AccessPolicy`) are also tested on their own. Small settings (48 x 64 images, 32 points).
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import struct
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
from _helpers import SMALL_SETTINGS, OutputLines

from lerobot_bavo.teleop.access import AccessPolicy, split_host
from lerobot_bavo.teleop.protocol import (
    MAX_KEYS,
    MAX_MESSAGE_BYTES,
    UNSET,
    CommandMessage,
    InputMessage,
    MessageError,
    parse_message,
)

aiohttp = pytest.importorskip("aiohttp", reason="bavo-teleop needs aiohttp")

SETTINGS = SMALL_SETTINGS
REPO = "tester/bavo_human_faults"
EPISODE_LENGTH = 400  # long enough that episodes end by `stop`, never by the step limit mid-test
IDENT = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


# ============================================================================ pure checks
@pytest.mark.parametrize(
    "text,field",
    [
        ("[1, 2]", "must be a JSON object, got a list"),
        ("5", "must be a JSON object, got a number"),
        ("null", "must be a JSON object, got null"),
        ('"input"', "must be a JSON object, got a string"),
        ("{", "not valid JSON"),
        ("[" * 30_000 + "]" * 30_000, "not valid JSON"),  # nested too deeply for the parser
        ('{"type": "input", "seq": 1e400}', "'seq' must be an integer"),
        ('{"type": "input", "seq": NaN}', "'seq' must be an integer"),
        ('{"type": "input", "seq": -1}', "'seq' must be in [0,"),
        ('{"type": "input", "seq": 9007199254740993}', "'seq' must be in [0,"),
        ('{"type": "input", "seq": true}', "'seq' must be an integer"),
        ('{"type": "shell"}', "'type' must be 'input' or 'cmd'"),
        ('{"seq": 3}', "'type' must be 'input' or 'cmd', got null"),
        ('{"type": "cmd", "cmd": "rm"}', "'cmd' must be one of"),
        ('{"type": "input", "keys": "w"}', "'keys' must be a list"),
        ('{"type": "input", "keys": ["w", "ctrl"]}', "keys[1] is not a known key"),
        ('{"type": "input", "keys": [["w"]]}', "keys[0] is not a known key"),
        ('{"type": "input", "taps": ["1"], "keys": ["w"], "x": 1}', "unknown field \"x\""),
        (
            '{"type": "input", "taps": ' + json.dumps(["1"] * (MAX_KEYS + 1)) + "}",
            f"'taps' has {MAX_KEYS + 1} entries",
        ),
        ('{"type": "input", "keys": ["pad17"]}', "keys[0] is not a known key"),
        ('{"type": "input", "pad": [0, 0, 2, 0]}', "pad[2] must be a finite number in [-1, 1]"),
        ('{"type": "input", "pad": [0, 0, 0, 0, 0]}', "'pad' must be null or a list of at most 4"),
        ('{"type": "input", "pad": [Infinity]}', "pad[0] must be a finite number"),
        ('{"type": "input", "xr": {"head": "abc"}}', "xr.head must be null or [x, y, z, qx, qy, qz, qw]"),
        ('{"type": "input", "xr": {"head": [0, 1, 0, 0, 0, 0, 0]}}', "xr.head: the quaternion's norm is 0"),
        ('{"type": "input", "xr": {"left": [0, 1, 0, 0, 0, 0, 1e-9]}}', "xr.left: the quaternion's norm"),
        (
            '{"type": "input", "xr": {"right": [0, NaN, 0, 0, 0, 0, 1]}}',
            "xr.right[1] must be a finite number",
        ),
        (
            '{"type": "input", "xr": {"right": [1e6, 0, 0, 0, 0, 0, 1]}}',
            "xr.right[0] must be a finite number in [-100",
        ),
        ('{"type": "input", "xr": {"right": [0, 0, 0, 0, 0, 0, 1, 5]}}', "xr.right must be null or"),
        (
            '{"type": "input", "xr": {"right_trigger": 3}}',
            "xr.right_trigger must be a finite number in [0, 1]",
        ),
        ('{"type": "input", "xr": {"nose": [0, 0, 0, 0, 0, 0, 1]}}', "unknown field \"nose\" in 'xr'"),
        ('{"type": "input", "xr": [1, 2]}', "'xr' must be null or an object"),
    ],
)
def test_parse_message_rejects_each_bad_field_by_name(text, field):
    with pytest.raises(MessageError) as e:
        parse_message(text)
    assert field in str(e.value), str(e.value)
    assert len(str(e.value)) < 200  # a large message is never echoed back whole


def test_parse_message_returns_small_typed_values():
    assert parse_message('{"type": "cmd", "cmd": "save"}') == CommandMessage("save")
    m = parse_message(
        '{"type": "input", "seq": 7, "keys": ["W", "shift"], "taps": [" ", "pad3"], "pad": null}'
    )
    assert m == InputMessage(seq=7, keys=("w", "shift"), taps=(" ", "pad3"), pad=None, xr=UNSET)
    m = parse_message(
        json.dumps(
            {
                "type": "input",
                "seq": 1,
                "keys": [],
                "xr": {"head": [0, 1.6, 0, 0, 0, 0, 1.2], "left": None, "right_trigger": 0.5},
            }
        )
    )
    assert m.keys == () and m.pad is UNSET
    # normalised
    assert m.xr == {"head": [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0], "left": None, "right_trigger": 0.5}
    with pytest.raises(MessageError, match=f"at most {MAX_MESSAGE_BYTES}"):
        parse_message(json.dumps({"type": "input", "keys": ["w"] * 20_000}))


def test_access_policy_checks_host_origin_and_token():
    p = AccessPolicy.for_bound("127.0.0.1", 8765, "tok")
    ok = dict(host="127.0.0.1:8765", origin="http://127.0.0.1:8765", token="tok", need_token=True)
    assert p.refusal(**ok) is None
    assert p.refusal(**dict(ok, host="localhost:8765", origin="http://localhost:8765")) is None
    # loopback names
    assert p.refusal(**dict(ok, host="localhost:8765", origin="http://127.0.0.1:8765")) is None
    assert p.refusal(**dict(ok, host="[::1]:8765", origin="http://[::1]:8765")) is None
    # not a browser page (browsers always send Origin on ws)
    assert p.refusal(**dict(ok, origin=None)) is None
    assert p.refusal(**dict(ok, token=None, need_token=False)) is None  # /static: header checks only
    cases = {
        "does not name this server": [dict(host="evil.example:8765"), dict(host="127.0.0.1:9999"),
                                      dict(host="127.0.0.1"), dict(host="127.0.0.1.evil.example:8765")],
        "is not a host": [dict(host="127.0.0.1:abc"), dict(host="[::1:8765")],
        "no Host header": [dict(host=None), dict(host="")],
        "is not this server's page": [dict(origin="http://evil.example"), dict(origin="null"),
                                      dict(origin="https://127.0.0.1:8765"), dict(origin="http://127.0.0.1:9999"),
                                      dict(origin="http://evil.example:8765"), dict(origin="file://")],
        "no token": [dict(token=None), dict(token="")],
        "wrong token": [dict(token="tok2"), dict(token="to"), dict(token="t\u00f6k")],
    }
    for reason, variants in cases.items():
        for v in variants:
            got = p.refusal(**dict(ok, **v))
            assert got is not None and reason in got, (v, got)
    # a non-loopback bind: only its own address; a wildcard bind: any IP literal, never a domain name
    lan = AccessPolicy.for_bound("192.168.1.5", 80, "tok")
    assert lan.refusal("192.168.1.5", "http://192.168.1.5", "tok", True) is None
    assert "does not name" in lan.refusal("localhost", None, "tok", True)
    anyip = AccessPolicy.for_bound("0.0.0.0", 8765, "tok")
    assert anyip.refusal("10.0.0.7:8765", "http://10.0.0.7:8765", "tok", True) is None
    assert "does not name" in anyip.refusal("rebind.example:8765", None, "tok", True)
    assert "is not this server's page" in anyip.refusal("10.0.0.7:8765", "http://10.0.0.8:8765", "tok", True)
    assert anyip.url("0.0.0.0") == "http://127.0.0.1:8765/?token=tok" and p.url("::1") == "http://[::1]:8765/?token=tok"
    assert split_host("[::1]:80") == ("::1", 80) and split_host("LocalHost") == ("localhost", None)


# ============================================================================ a live server
class LiveServer:
    """`TeleopServer` + `TeleopSession` on 127.0.0.1:<free port>, on an event loop in a background thread."""

    def __init__(self, root):
        from lerobot_bavo.teleop.server import TeleopServer
        from lerobot_bavo.teleop.session import TeleopConfig, TeleopSession

        cfg = TeleopConfig("cube_handoff", "stage", REPO, root, seed=11, settings=SETTINGS,
                           episode_length=EPISODE_LENGTH, third_person_height=48)
        self.server = TeleopServer(None)
        self.session = TeleopSession(cfg, publish=self.server.publish)
        self.server.session = self.session
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="test-teleop-loop", daemon=True)
        self.thread.start()
        self.url = self._call(self.server.start("127.0.0.1", 0), 300)
        self.base, query = self.url.split("/?")
        self.token = query.removeprefix("token=")
        assert self.token == self.server.token
        self.port = int(self.base.rsplit(":", 1)[1])
        self.ws_url = f"ws://127.0.0.1:{self.port}/ws"

    def _call(self, coro, timeout):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def close(self):
        try:
            self._call(self.server.stop(), 300)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(30)
            self.loop.close()


@pytest.fixture(scope="module")
def live_server(tmp_path_factory):
    srv = LiveServer(tmp_path_factory.mktemp("teleop_faults") / "human")
    yield srv
    srv.close()
    assert srv.session.error is None


@pytest.fixture
def live(live_server):
    """The module's server, idle (whatever a test before left behind)."""
    session = live_server.session
    if session.state != "idle":
        session.operator_joined()
        session.command("discard")
        t0 = time.monotonic()
        while session.state != "idle" and time.monotonic() - t0 < 60:
            time.sleep(0.05)
    assert session.state == "idle" and session.is_alive()
    return live_server


class Page:
    """A websocket client as the real page is (the run's token, the server's own Origin); it reads
    everything the server sends: text messages into `texts`, frame headers into `headers`."""

    def __init__(self, ws):
        self.ws = ws
        self.texts: list[dict] = []
        self.headers: list[dict] = []
        self.task = asyncio.ensure_future(self._read())

    @classmethod
    async def open(cls, http, live, **kw):
        kw.setdefault("params", {"token": live.token})
        kw.setdefault("origin", live.base)
        return cls(await http.ws_connect(live.ws_url, **kw))

    async def _read(self):
        async for msg in self.ws:
            if msg.type == aiohttp.WSMsgType.TEXT:
                self.texts.append(json.loads(msg.data))
            elif msg.type == aiohttp.WSMsgType.BINARY:
                (n,) = struct.unpack_from("<I", msg.data)
                self.headers.append(json.loads(msg.data[12:12 + n]))

    def errors(self) -> list[str]:
        return [m["error"] for m in self.texts if m.get("type") == "error"]

    async def send(self, msg) -> None:
        await self.ws.send_str(msg if isinstance(msg, str) else json.dumps(msg))

    async def error_for(self, msg) -> str:
        """Send one message the server must refuse; returns the error it answers."""
        n = len(self.errors())
        await self.send(msg)
        await until(lambda: len(self.errors()) > n, 30, f"an error answer to {str(msg)[:60]}")
        return self.errors()[n]

    async def close(self) -> None:
        await self.ws.close()
        await self.task


async def until(pred, timeout=60.0, what="condition"):
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout:
            raise TimeoutError(f"timed out waiting for {what}")
        await asyncio.sleep(0.02)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 240))


async def start_episode(page, live) -> None:
    session = live.session
    assert session.state == "idle", session.state
    await page.send({"type": "cmd", "cmd": "start"})
    await until(
        lambda: session.state == "running" and session.agent is not None and len(session.agent.inputs) > 2,
        what="a running episode",
    )


async def stop_and_save(page, live) -> dict:
    """End the running episode (X), save it (Enter); returns its collection-record entry."""
    session = live.session
    n = len(session.saved)
    await page.send({"type": "cmd", "cmd": "stop"})
    await until(lambda: session.state == "ended", what="the episode's end")
    await page.send({"type": "cmd", "cmd": "save"})
    await until(lambda: len(session.saved) == n + 1 and session.state == "idle", 120, what="the save")
    return session.saved[-1]


def read_input_log(live, entry) -> list[dict]:
    lines = (live.session.root / entry["input_log"]).read_text().splitlines()
    return [json.loads(line) for line in lines[1:]]


def right_target(live) -> np.ndarray:
    return live.session.agent.controller.arms["right"].pos.copy()


# ============================================================================ 1. other sites, rebinding, no
# token
def test_other_sites_rebinding_and_missing_token_are_refused_and_the_episode_survives(live):
    """A page on another site or a rebinding domain name cannot connect (403 with the reason) while an
    ended episode waits to be saved; the operator's page then saves it."""
    host_evil = f"rebind.example:{live.port}"

    async def refused(http, url, reason, **kw):
        async with http.get(url, **kw) as r:  # the reason, in plain HTTP
            body = await r.text()
            assert r.status == 403 and reason in body, (r.status, body)
        if url.startswith(live.ws_url.replace("ws://", "http://")):  # and the websocket upgrade itself
            headers = dict(kw.get("headers", {}))
            with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                await http.ws_connect(
                    url.replace("http://", "ws://"), headers=headers, params=kw.get("params")
                )
            assert e.value.status == 403

    async def scenario():
        async with aiohttp.ClientSession() as http:
            page = await Page.open(http, live)
            await start_episode(page, live)
            await page.send({"type": "input", "seq": 1, "keys": ["d"], "taps": ["2"]})
            await asyncio.sleep(0.3)
            await page.send({"type": "cmd", "cmd": "stop"})
            await until(lambda: live.session.state == "ended", what="the episode's end")
            pending_len = live.session.pending[0].length

            ws_http = f"http://127.0.0.1:{live.port}/ws"
            tok = {"token": live.token}
            await refused(http, ws_http, "Origin 'http://evil.example' is not this server's page",
                          params=tok, headers={"Origin": "http://evil.example"})
            await refused(http, ws_http, "Origin 'null'", params=tok, headers={"Origin": "null"})
            await refused(http, ws_http, "does not name this server", params=tok,
                          headers={"Host": host_evil, "Origin": f"http://{host_evil}"})
            await refused(http, ws_http, "no token", headers={"Origin": live.base})
            wrong = live.token[:-1] + ("y" if live.token.endswith("x") else "x")  # always differs
            await refused(http, ws_http, "wrong token", params={"token": wrong},
                          headers={"Origin": live.base})
            await refused(http, live.base + "/", "no token")
            await refused(http, live.base + "/favicon.ico", "no token")  # any other path, too
            await refused(http, live.url, "does not name this server", headers={"Host": host_evil})
            await refused(
                http, live.base + "/static/app.js", "does not name this server", headers={"Host": host_evil}
            )
            await refused(http, live.base + "/static/app.js", "is not this server's page",
                          headers={"Origin": "http://evil.example"})
            # the operator's own requests still work: the page, its script, a second page by `localhost`
            async with http.get(live.url) as r:
                assert r.status == 200 and "<title>bavo-teleop</title>" in await r.text()
                assert r.headers["Referrer-Policy"] == "no-referrer"
            async with http.get(live.base + "/static/app.js") as r:
                assert r.status == 200 and "token=${encodeURIComponent(TOKEN)}" in await r.text()
            other = await Page.open(http, live, origin=f"http://localhost:{live.port}",
                                    headers={"Host": f"localhost:{live.port}"})
            await until(lambda: other.texts, what="the status for the localhost page")
            assert other.texts[0]["state"] == "ended"
            await other.close()
            # nothing was discarded: the episode that was waiting is saved whole
            assert live.session.state == "ended" and live.session.pending[0].length == pending_len
            n = len(live.session.saved)
            await page.send({"type": "cmd", "cmd": "save"})
            await until(lambda: len(live.session.saved) == n + 1, 120, what="the save")
            await page.close()
        return pending_len

    length = run(scenario())
    entry = live.session.saved[-1]
    assert len(read_input_log(live, entry)) == length
    assert live.session.state == "idle" and live.session.is_alive()


# ============================================================================ 2. bad messages
BAD_MESSAGES = [
    ("[1, 2]", "must be a JSON object"),
    ("5", "must be a JSON object"),
    ("null", "must be a JSON object"),
    ('{"type": "input", "seq": 1e400}', "'seq' must be an integer"),
    ({"type": "input", "seq": 2, "xr": {"head": "abc"}}, "xr.head must be null or"),
    (
        {"type": "input", "seq": 3, "keys": [], "xr": {"head": [0, 1.6, 0, 0, 0, 0, 0]}},
        "quaternion's norm is 0",
    ),
    (
        {"type": "input", "seq": 4, "keys": ["w"], "pad": [0, 0, float("nan"), 0]},
        "pad[2] must be a finite number",
    ),
    ({"type": "input", "seq": 5, "keys": ["w"] * 33}, "'keys' has 33 entries"),
    ({"type": "input", "seq": 6, "taps": ["1", "exec"]}, "taps[1] is not a known key"),
    ({"type": "cmd", "cmd": "format"}, "'cmd' must be one of"),
    ("[" * 30_000 + "]" * 30_000, "not valid JSON"),
]


def test_bad_messages_are_answered_and_the_episode_goes_on(live):
    """Every bad message (the crashes of issue 29 among them) gets an error naming the field; none
    reaches the simulation thread, the episode keeps running, and a valid input still moves the arm."""
    session = live.session

    async def scenario():
        async with aiohttp.ClientSession() as http:
            page = await Page.open(http, live)
            await start_episode(page, live)
            await page.send({"type": "input", "seq": 1, "keys": [], "taps": ["2"]})
            await until(lambda: session.agent.controller.active == "right", what="the right arm selected")
            before = right_target(live)
            for msg, reason in BAD_MESSAGES:
                error = await page.error_for(msg)
                assert reason in error, (
                    (msg if isinstance(msg, str) else json.dumps(msg))[:80] + " -> " + error
                )
            await page.ws.send_bytes(b"\x00\x01")
            await until(
                lambda: "binary messages are not accepted" in " ".join(page.errors()), what="binary refusal"
            )
            assert session.state == "running" and session.is_alive() and session.error is None
            np.testing.assert_array_equal(right_target(live), before)  # no bad message moved anything
            assert not session.agent.failed_ticks
            # the service still works: a valid input moves the right arm's target along +y
            await page.send({"type": "input", "seq": 7, "keys": ["w"], "taps": []})
            await until(
                lambda: right_target(live)[1] - before[1] > 0.02, what="the arm moving on a valid input"
            )
            await page.send({"type": "input", "seq": 8, "keys": [], "taps": []})
            entry = await stop_and_save(page, live)
            await page.close()
            return entry

    entry = run(scenario())
    log = read_input_log(live, entry)
    assert {tuple(t["keys"]) for t in log} <= {(), ("w",)} and max(t["seq"] for t in log) == 8
    assert all("xr" not in t and "pad" not in t for t in log)  # nothing of the refused messages was logged


def test_an_oversized_message_closes_only_its_own_connection(live, caplog):
    """A message over MAX_MESSAGE_BYTES (the 1 MB keys message of issue 29) closes that websocket with
    1009 before it is parsed; the server and the other pages go on. The page itself reads 1009, or 1006
    when the server's close resets its socket while it is still writing the message (seen in CI), so the
    1009 is checked where it is sent: the server's log."""
    async def scenario():
        async with aiohttp.ClientSession() as http:
            watcher = await Page.open(http, live)
            big = await Page.open(http, live)
            await big.send(json.dumps({"type": "input", "seq": 1, "keys": ["w"] * (1 << 18)}))  # ~1.3 MB
            await asyncio.wait_for(big.task, 30)
            closed = (aiohttp.WSCloseCode.MESSAGE_TOO_BIG, aiohttp.WSCloseCode.ABNORMAL_CLOSURE)
            assert big.ws.close_code in closed
            await until(lambda: "its connection was closed (1009)" in caplog.text, what="the server's 1009")
            assert live.session.input.keys == set()
            assert not watcher.ws.closed
            await until(lambda: watcher.texts, what="the watcher's status")
            fresh = await Page.open(http, live)  # and a new page connects as usual
            await until(
                lambda: fresh.texts and fresh.texts[0]["type"] == "status", what="a new page's status"
            )
            await fresh.close()
            await watcher.close()

    run(scenario())
    assert live.session.state == "idle" and live.session.is_alive()


# ============================================================================ 3. disconnects, bounded inputs
def test_a_page_that_goes_away_lets_go_of_its_keys_and_the_episode_pauses(live):
    """Hold W and R, then close the socket: the held keys are released and, with no page left, the
    episode pauses (no tick simulated or recorded); a page that connects again resumes it with the arm
    holding still. With two pages, the controlling one leaving releases its input but does not pause."""
    session = live.session

    async def scenario():
        async with aiohttp.ClientSession() as http:
            page = await Page.open(http, live)
            await start_episode(page, live)
            await page.send({"type": "input", "seq": 1, "keys": ["w", "r"], "taps": ["2"]})
            await until(
                lambda: sum(1 for t in session.agent.inputs if t["keys"]) >= 5, what="ticks with held keys"
            )
            await page.close()
            await until(lambda: session.state == "paused", 30, what="the pause")
            assert session.input.keys == set() and session.input.pad is None and session.input.xr is None
            ticks = len(session.agent.inputs)
            target = right_target(live)
            qpos = session.recorder.env.data.qpos.copy()
            await asyncio.sleep(0.6)  # 15 ticks' worth of time: nothing is simulated or recorded
            assert len(session.agent.inputs) == ticks and session.state == "paused"
            np.testing.assert_array_equal(session.recorder.env.data.qpos, qpos)

            page = await Page.open(http, live)  # reconnect: the episode goes on, the arm holds still
            await until(lambda: session.state == "running" and len(session.agent.inputs) > ticks + 10,
                        what="the resumed episode")
            np.testing.assert_array_equal(right_target(live), target)

            second = await Page.open(http, live)  # two pages; the second one drives, then leaves
            await second.send({"type": "input", "seq": 2, "keys": ["a"], "taps": []})
            await until(lambda: session.input.keys == {"a"}, what="the second page's keys")
            await second.close()
            await until(lambda: session.input.keys == set(), what="the second page's keys released")
            resumed = len(session.agent.inputs)
            await until(
                lambda: len(session.agent.inputs) > resumed + 5, what="ticks after the second page left"
            )
            assert session.state == "running"  # the first page is still there: no pause
            entry = await stop_and_save(page, live)
            await page.close()
            return entry, ticks

    entry, ticks = run(scenario())
    log = read_input_log(live, entry)
    held = [k for k, t in enumerate(log) if t["keys"] == ["r", "w"]]
    assert held and held[-1] < ticks  # no tick after the disconnect was driven by the released keys
    assert all(t["keys"] in ([], ["a"]) for t in log[ticks:])


def test_taps_and_the_per_tick_log_stay_small(live):
    """90 k taps sent while idle, or a tick flooded with taps, leave at most MAX_PENDING_TAPS queued
    and a log entry of a few hundred bytes."""
    session = live.session
    cap = session.input.MAX_PENDING_TAPS

    async def scenario():
        async with aiohttp.ClientSession() as http:
            page = await Page.open(http, live)
            for k in range(90_000 // MAX_KEYS):  # idle: nothing consumes taps
                await page.send({"type": "input", "seq": k, "keys": [], "taps": ["1"] * MAX_KEYS})
            await page.send({"type": "input", "seq": 99_999, "keys": ["w"], "taps": ["3"]})
            await until(lambda: session.input.seq == 99_999, what="the flood processed")
            assert len(session.input.taps) == cap and session.input.taps[-1] == "3"
            await page.send({"type": "input", "seq": 0, "keys": [], "taps": []})
            await start_episode(page, live)
            for k in range(200):  # taps flooding in during the episode
                await page.send({"type": "input", "seq": 100_000 + k, "keys": ["w", "shift"],
                                 "taps": ["1", "2"] * (MAX_KEYS // 2)})
            await until(lambda: session.input.seq == 100_199, what="the in-episode flood processed")
            await page.send({"type": "input", "seq": 100_200, "keys": [], "taps": []})
            entry = await stop_and_save(page, live)
            await page.close()
            return entry

    entry = run(scenario())
    log = read_input_log(live, entry)
    assert max(len(t["taps"]) for t in log) <= cap
    assert max(len(json.dumps(t)) for t in log) < 600
    assert (live.session.root / entry["input_log"]).stat().st_size < 600 * (len(log) + 1)


# ============================================================================ sim-thread failures
def test_a_failing_tick_or_save_keeps_the_thread_and_the_episode(live, monkeypatch):
    """An unexpected exception in one tick (here: the controller raises on the T key) holds the arms for
    that tick and is reported to the page; the episode goes on. A save that fails keeps the ended episode
    pending, reported, and the next save writes it."""
    from lerobot_bavo.teleop.controls import TeleopController
    from lerobot_bavo.teleop.session import HumanDataset

    session = live.session
    step = TeleopController.step

    def faulty_step(self, inp):
        if "t" in inp.keys:
            raise RuntimeError("injected controller fault")
        return step(self, inp)

    monkeypatch.setattr(TeleopController, "step", faulty_step)
    save = HumanDataset.save
    calls = []

    def failing_once_save(self, record, inputs):
        calls.append(record.seed)
        if len(calls) == 1:
            raise OSError(28, "No space left on device (injected)")
        return save(self, record, inputs)

    monkeypatch.setattr(HumanDataset, "save", failing_once_save)

    async def scenario():
        async with aiohttp.ClientSession() as http:
            page = await Page.open(http, live)
            await start_episode(page, live)
            await page.send({"type": "input", "seq": 1, "keys": ["t"], "taps": []})
            await until(
                lambda: any("injected controller fault" in e for e in page.errors()), what="the tick error"
            )
            await page.send({"type": "input", "seq": 2, "keys": [], "taps": []})
            await until(lambda: session.agent.inputs[-1]["keys"] == [], what="the next input in effect")
            failed = list(session.agent.failed_ticks)
            ticks = len(session.agent.inputs)
            await until(lambda: len(session.agent.inputs) > ticks + 5, what="ticks after the failure")
            assert session.state == "running" and session.is_alive()
            assert len(session.agent.failed_ticks) == len(failed)  # only the ticks with T failed
            await page.send({"type": "cmd", "cmd": "stop"})
            await until(lambda: session.state == "ended", what="the episode's end")
            length = session.pending[0].length
            n = len(session.saved)
            await page.send({"type": "cmd", "cmd": "save"})
            await until(lambda: any("No space left" in e for e in page.errors()), 60, what="the save error")
            await until(lambda: session.state == "ended", what="the episode kept")
            assert (
                session.pending is not None
                and session.pending[0].length == length
                and len(session.saved) == n
            )
            await page.send({"type": "cmd", "cmd": "save"})  # try again: it is written
            await until(
                lambda: len(session.saved) == n + 1 and session.state == "idle", 120, what="the second save"
            )
            await page.close()
            return failed, length

    failed, length = run(scenario())
    assert failed and len(calls) == 2
    log = read_input_log(live, live.session.saved[-1])
    assert len(log) == length and all(log[k]["keys"] == ["t"] for k in failed)
    assert live.session.error is None and live.session.is_alive()


# ============================================================================ the CLI
# The address line of `bavo-teleop`. The token ends where the URL does: a `\b` there never matched a token
# ending in "-" (1 run in 64), and the test then read the serving process's output for ever (CI timed out).
SERVING_LINE = r"serving (http://127\.0\.0\.1:\d+)/\?token=([\w-]{32})(?![\w-])"


def test_the_serving_line_pattern_takes_every_token_whole():
    from lerobot_bavo.teleop.access import new_token

    for token in [new_token() for _ in range(200)] + ["a" * 31 + "-", "-" * 32, "_" * 32]:
        line = f"bavo-teleop: serving http://127.0.0.1:8765/?token={token} (dataset /tmp/x); Ctrl+C stops"
        m = re.search(SERVING_LINE, line)
        assert m and m.group(2) == token, token


def test_cli_prints_the_address_with_its_token_and_refuses_requests_without_it(tmp_path):
    """`bavo-teleop` prints http://127.0.0.1:<port>/?token=<token>; that address serves the page, the
    same address without the token (or with another run's) gets 403 with the reason."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lerobot_bavo.teleop",
            "--task",
            "cube_handoff",
            "--repo-id",
            REPO,
            "--root",
            str(tmp_path / "human"),
            "--port",
            "0",
            "--image-height",
            "48",
            "--image-width",
            "64",
            "--n-points",
            "32",
            "--third-person-height",
            "48",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1"),
    )
    output = OutputLines(proc)
    try:
        m = output.wait_for(SERVING_LINE)
        base, token = m.groups()
        with urllib.request.urlopen(f"{base}/?token={token}", timeout=30) as r:
            assert r.status == 200 and b"bavo-teleop" in r.read()
        for url, reason in ((f"{base}/", b"no token"), (f"{base}/?token={token[::-1]}", b"wrong token")):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(url, timeout=30)
            assert e.value.code == 403 and reason in e.value.read()
    finally:
        proc.send_signal(signal.SIGINT)
        out = output.rest(timeout=120)
    assert proc.wait(30) == 0, "".join(output.lines)
    assert "refused GET / from 127.0.0.1: no token" in out
