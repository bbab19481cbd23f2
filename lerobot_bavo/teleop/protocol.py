"""The page -> server messages of `bavo-teleop`, validated as a whole before anything acts on them.

A websocket message is untrusted text. `parse_message` turns one message into a small, typed,
bounded value (`InputMessage` or `CommandMessage`) or raises `MessageError` naming the field at
fault; nothing else in the server reads the raw JSON. Why a whole-message check up front rather
than care at each use: the input is used on the simulation thread (IK, quaternion maths), where a
bad value used to raise and end the thread; and each tick's input is written to the episode's log,
so its size must be bounded by construction, not by what a client chooses to send.

Messages (JSON objects):
    {"type": "cmd", "cmd": "start" | "stop" | "save" | "discard" | "rerecord"}
    {"type": "input", "seq": int, "keys": [...], "taps": [...], "pad": [...] | null, "xr": {...} | null}
        seq: the page's input counter, 0 <= seq <= 2**53 - 1 (latency measurement only);
        keys: keys / gamepad buttons held now, taps: pressed since the last message; each at most
            MAX_KEYS entries from `KNOWN_KEYS` (lower-case; "pad<i>" for gamepad button i < 17);
        pad: null or at most 4 gamepad axes in [-1, 1];
        xr: null or {"head" | "left" | "right": null or [x, y, z, qx, qy, qz, qw],
            "left_trigger" | "right_trigger": null or a number in [0, 1]}; positions within
            MAX_XR_POSITION metres, quaternions of norm in QUAT_NORM_RANGE (then normalised).
    A field left out of an input message leaves that part of the operator's input as it was
    (the page's keyboard / gamepad messages carry keys, taps and pad; its WebXR messages keys,
    taps and xr).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from lerobot_bavo.teleop.controls import ARM_KEYS, GRIPPER_KEY, LOOK_AT_KEY, MOTION_KEYS

MAX_MESSAGE_BYTES = 64 * 1024  # the websocket's max_msg_size: larger messages close the connection (1009)
MAX_KEYS = 32  # entries of `keys`, and of `taps`, in one message
MAX_PAD_BUTTONS = 17  # the Gamepad API's standard mapping: buttons 0..16
MAX_SEQ = 2**53 - 1  # the largest integer a page's JavaScript counts exactly
MAX_XR_POSITION = 100.0  # metres from the XR reference space's origin
QUAT_NORM_RANGE = (0.5, 1.5)  # WebXR sends unit quaternions; far from 1 is not a rotation
COMMANDS = ("start", "stop", "save", "discard", "rerecord")
XR_POSES = ("head", "left", "right")
XR_TRIGGERS = ("left_trigger", "right_trigger")
KNOWN_KEYS = frozenset(
    [*MOTION_KEYS, "shift", *ARM_KEYS, GRIPPER_KEY, LOOK_AT_KEY] + [f"pad{i}" for i in range(MAX_PAD_BUTTONS)]
)
INPUT_FIELDS = frozenset({"type", "seq", "keys", "taps", "pad", "xr"})


class MessageError(ValueError):
    """A page message that is not valid; the text names the field and is sent back to the page."""


class _Unset:
    """The field was not in the message (the input it describes is left as it was)."""

    def __repr__(self) -> str:
        return "UNSET"


UNSET = _Unset()


@dataclass(frozen=True)
class CommandMessage:
    cmd: str


@dataclass(frozen=True)
class InputMessage:
    """One validated input message; `UNSET` fields were not sent."""

    seq: int = 0
    keys: tuple[str, ...] | _Unset = UNSET
    taps: tuple[str, ...] = ()
    pad: tuple[float, ...] | None | _Unset = UNSET
    xr: dict | None | _Unset = UNSET


def parse_message(text: str | bytes) -> InputMessage | CommandMessage:
    """Parse and check one websocket text message; raises `MessageError` naming what is wrong."""
    size = len(text) if isinstance(text, bytes) else len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_MESSAGE_BYTES:
        raise MessageError(f"message of {size} bytes, at most {MAX_MESSAGE_BYTES}")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as e:  # RecursionError: nested too deeply
        raise MessageError(f"not valid JSON ({type(e).__name__}: {str(e)[:80]})") from None
    if not isinstance(data, dict):
        raise MessageError(f"a message must be a JSON object, got {_kind(data)}")
    kind = data.get("type")
    if kind == "cmd":
        return parse_command(data)
    if kind == "input":
        return parse_input(data)
    raise MessageError(f"'type' must be 'input' or 'cmd', got {_short(kind)}")


def parse_command(data: dict) -> CommandMessage:
    extra = set(data) - {"type", "cmd"}
    if extra:
        raise MessageError(f"unknown field {_short(sorted(extra)[0])} in a cmd message")
    cmd = data.get("cmd")
    if cmd not in COMMANDS:
        raise MessageError(f"'cmd' must be one of {', '.join(COMMANDS)}, got {_short(cmd)}")
    return CommandMessage(cmd)


def parse_input(data: dict) -> InputMessage:
    """An input message (a dict already decoded from JSON) -> `InputMessage`."""
    extra = set(data) - INPUT_FIELDS
    if extra:
        raise MessageError(f"unknown field {_short(sorted(extra)[0])} in an input message")
    return InputMessage(
        seq=_seq(data.get("seq", 0)),
        keys=_keys("keys", data["keys"]) if "keys" in data else UNSET,
        taps=_keys("taps", data.get("taps", [])),
        pad=_pad(data["pad"]) if "pad" in data else UNSET,
        xr=_xr(data["xr"]) if "xr" in data else UNSET,
    )


# ---------------------------------------------------------------------- fields
def _seq(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise MessageError(f"'seq' must be an integer, got {_short(value)}")
    if not 0 <= value <= MAX_SEQ:
        raise MessageError(f"'seq' must be in [0, {MAX_SEQ}], got {_short(value)}")
    return value


def _keys(name: str, value) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise MessageError(f"{name!r} must be a list of key names, got {_kind(value)}")
    if len(value) > MAX_KEYS:
        raise MessageError(f"{name!r} has {len(value)} entries, at most {MAX_KEYS}")
    out = []
    for i, k in enumerate(value):
        if not isinstance(k, str) or len(k) > 8 or k.lower() not in KNOWN_KEYS:
            raise MessageError(f"{name}[{i}] is not a known key: {_short(k)}")
        out.append(k.lower())
    return tuple(out)


def _number(name: str, value, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MessageError(f"{name} must be a number, got {_short(value)}")
    v = float(value) if not isinstance(value, int) or abs(value) <= 2**64 else math.inf
    if not math.isfinite(v) or not low <= v <= high:
        raise MessageError(f"{name} must be a finite number in [{low:g}, {high:g}], got {_short(value)}")
    return v


def _pad(value) -> tuple[float, ...] | None:
    if value is None:
        return None
    if not isinstance(value, list) or len(value) > 4:
        raise MessageError(f"'pad' must be null or a list of at most 4 gamepad axes, got {_short(value)}")
    return tuple(_number(f"pad[{i}]", v, -1.0, 1.0) for i, v in enumerate(value))


def _pose(name: str, value) -> list[float] | None:
    """[x, y, z, qx, qy, qz, qw] with a finite position in range and a quaternion near unit norm,
    normalised."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 7:
        raise MessageError(f"xr.{name} must be null or [x, y, z, qx, qy, qz, qw], got {_short(value)}")
    p = [_number(f"xr.{name}[{i}]", v, -MAX_XR_POSITION, MAX_XR_POSITION) for i, v in enumerate(value[:3])]
    q = [_number(f"xr.{name}[{i + 3}]", v, -2.0, 2.0) for i, v in enumerate(value[3:])]
    norm = math.sqrt(sum(c * c for c in q))
    lo, hi = QUAT_NORM_RANGE
    if not lo <= norm <= hi:
        raise MessageError(f"xr.{name}: the quaternion's norm is {norm:.3g}, a rotation needs about 1 "
                           f"(accepted: {lo}..{hi})")
    return p + [c / norm for c in q]


def _xr(value) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise MessageError(f"'xr' must be null or an object, got {_kind(value)}")
    extra = set(value) - set(XR_POSES) - set(XR_TRIGGERS)
    if extra:
        raise MessageError(f"unknown field {_short(sorted(extra)[0])} in 'xr'")
    out = {}
    for name in XR_POSES:
        if name in value:
            out[name] = _pose(name, value[name])
    for name in XR_TRIGGERS:
        if name in value:
            out[name] = None if value[name] is None else _number(f"xr.{name}", value[name], 0.0, 1.0)
    return out


# ---------------------------------------------------------------------- error texts
def _kind(value) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null",
            int: "a number", float: "a number"}.get(type(value), type(value).__name__)


def _short(value) -> str:
    """A value for an error message, cut short (messages may be large)."""
    text = json.dumps(value) if isinstance(value, (str, list, dict, bool, type(None))) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
