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

from lerobot_bavo.features import ObservationSettings
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

SETTINGS = ObservationSettings(image_height=48, image_width=64, n_points=32)
REPO = "tester/bavo_human_faults"
EPISODE_LENGTH = 400  # long enough that episodes end by `stop`, never by the step limit mid-test
IDENT = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


# ============================================================================ pure checks
@pytest.mark.parametrize("text,field", [
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
    ('{"type": "input", "taps": ' + json.dumps(["1"] * (MAX_KEYS + 1)) + "}", f"'taps' has {MAX_KEYS + 1} entries"),
    ('{"type": "input", "keys": ["pad17"]}', "keys[0] is not a known key"),
    ('{"type": "input", "pad": [0, 0, 2, 0]}', "pad[2] must be a finite number in [-1, 1]"),
    ('{"type": "input", "pad": [0, 0, 0, 0, 0]}', "'pad' must be null or a list of at most 4"),
    ('{"type": "input", "pad": [Infinity]}', "pad[0] must be a finite number"),
    ('{"type": "input", "xr": {"head": "abc"}}', "xr.head must be null or [x, y, z, qx, qy, qz, qw]"),
    ('{"type": "input", "xr": {"head": [0, 1, 0, 0, 0, 0, 0]}}', "xr.head: the quaternion's norm is 0"),
    ('{"type": "input", "xr": {"left": [0, 1, 0, 0, 0, 0, 1e-9]}}', "xr.left: the quaternion's norm"),
    ('{"type": "input", "xr": {"right": [0, NaN, 0, 0, 0, 0, 1]}}', "xr.right[1] must be a finite number"),
    ('{"type": "input", "xr": {"right": [1e6, 0, 0, 0, 0, 0, 1]}}', "xr.right[0] must be a finite number in [-100"),
    ('{"type": "input", "xr": {"right": [0, 0, 0, 0, 0, 0, 1, 5]}}', "xr.right must be null or"),
    ('{"type": "input", "xr": {"right_trigger": 3}}', "xr.right_trigger must be a finite number in [0, 1]"),
    ('{"type": "input", "xr": {"nose": [0, 0, 0, 0, 0, 0, 1]}}', "unknown field \"nose\" in 'xr'"),
    ('{"type": "input", "xr": [1, 2]}', "'xr' must be null or an object"),
])
def test_parse_message_rejects_each_bad_field_by_name(text, field):
    with pytest.raises(MessageError) as e:
        parse_message(text)
    assert field in str(e.value), str(e.value)
    assert len(str(e.value)) < 200  # a large message is never echoed back whole


def test_parse_message_returns_small_typed_values():
    assert parse_message('{"type": "cmd", "cmd": "save"}') == CommandMessage("save")
    m = parse_message('{"type": "input", "seq": 7, "keys": ["W", "shift"], "taps": [" ", "pad3"], "pad": null}')
    assert m == InputMessage(seq=7, keys=("w", "shift"), taps=(" ", "pad3"), pad=None, xr=UNSET)
    m = parse_message(json.dumps({"type": "input", "seq": 1, "keys": [],
                                  "xr": {"head": [0, 1.6, 0, 0, 0, 0, 1.2], "left": None, "right_trigger": 0.5}}))
    assert m.keys == () and m.pad is UNSET
    assert m.xr == {"head": [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0], "left": None, "right_trigger": 0.5}  # normalised
    with pytest.raises(MessageError, match=f"at most {MAX_MESSAGE_BYTES}"):
        parse_message(json.dumps({"type": "input", "keys": ["w"] * 20_000}))


def test_access_policy_checks_host_origin_and_token():
    p = AccessPolicy.for_bound("127.0.0.1", 8765, "tok")
    ok = dict(host="127.0.0.1:8765", origin="http://127.0.0.1:8765", token="tok", need_token=True)
    assert p.refusal(**ok) is None
    assert p.refusal(**dict(ok, host="localhost:8765", origin="http://localhost:8765")) is None
    assert p.refusal(**dict(ok, host="localhost:8765", origin="http://127.0.0.1:8765")) is None  # loopback names
    assert p.refusal(**dict(ok, host="[::1]:8765", origin="http://[::1]:8765")) is None
    assert p.refusal(**dict(ok, origin=None)) is None  # not a browser page (browsers always send Origin on ws)
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
