"""`bavo-view --web`: serve a recording with rerun's own CLI, bound to one address (loopback by default).

Why not the SDK's `RecordingStream.serve_grpc` + `rerun.serve_web_viewer` (what `--web` used before):
- rerun 0.33's Python SDK takes no bind address: both servers listened on 0.0.0.0, so the recording and the
  viewer were reachable from the network. Its CLI takes `--bind`, so `--web` now runs
  `rerun --serve-web --bind ADDR` as a child process, with no recording on its command line: given a file (or
  stdin) that server keeps a core busy after loading it (measured: ~100 % of a core, idle, rerun 0.33.1),
  without one it idles at 0 %.
- `serve_grpc` could hang for good before returning its URL (reproduced here: 2 of 7 starts in a row; Ctrl-C
  did not stop them). py-spy showed the main thread blocked inside the binding on a channel while holding the
  GIL, and a tokio worker thread waiting for the GIL to release a numpy-backed Arrow buffer: a deadlock inside
  rerun, not a port race. The recording is now sent to the server by a short-lived child process
  (`send_recording`, the SDK as a gRPC client: 10 of 10 sends worked), with a timeout, so a hang there is
  killed and reported.
- A taken port made `serve_grpc` return a URL anyway (the bind failed later in a thread, logged only), and
  `serve_web_viewer` raise a bare RuntimeError. Ports are now checked (or picked, with 0) before the start,
  and the URL is printed only once both ports accept connections and the recording is in.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote

DEFAULT_BIND = "127.0.0.1"
START_TIMEOUT_S = 60.0  # the rerun CLI is a ~230 MB binary: a cold start on a loaded machine takes seconds


class ServeError(RuntimeError):
    """The viewer could not be served; the message says why and what to do."""


def rerun_executable() -> Path:
    """The rerun CLI installed with the rerun SDK (`rerun_cli/rerun`; `RERUN_CLI_PATH` overrides it, as for
    rerun's own `rerun` script)."""
    import importlib.util

    if os.environ.get("RERUN_CLI_PATH"):
        return Path(os.environ["RERUN_CLI_PATH"])
    spec = importlib.util.find_spec("rerun_cli")
    path = Path(spec.origin).parent / "rerun" if spec and spec.origin else None
    if path is None or not path.is_file():
        raise ServeError(
            "the rerun CLI (package rerun_cli, installed with rerun-sdk) is missing; reinstall rerun-sdk"
        )
    return path


def client_host(bind: str) -> str:
    """Where this machine reaches a server bound to `bind` (a wildcard bind is reached on loopback)."""
    return {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(bind, bind)


def _family(host: str) -> int:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def free_port(bind: str, port: int) -> int:
    """`port` if it can be bound on `bind` now, a free port chosen by the system if `port` is 0; ServeError
    naming the port otherwise (another bavo-view or rerun is probably using it)."""
    with socket.socket(_family(bind), socket.SOCK_STREAM) as s:
        # as the servers do: a port in TIME_WAIT is free
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((bind, port))
        except OSError as e:
            raise ServeError(
                f"cannot listen on {bind}:{port} ({e.strerror}); pass another port, or 0 for a free one"
            ) from None
        return s.getsockname()[1]


def viewer_url(host: str, web_port: int, grpc_port: int) -> str:
    """The web viewer's address, with the gRPC server it reads as its `url` parameter."""
    name = f"[{host}]" if ":" in host else host
    return f"http://{name}:{web_port}/?url=" + quote(f"rerun+http://{name}:{grpc_port}/proxy", safe="")


def _accepts(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1.0):
            return True
    except OSError:
        return False


def _die_with_parent():
    """A `preexec_fn` that makes the child get SIGTERM when this process dies (even by SIGKILL), so no server
    outlives bavo-view; None where the OS has no such call (then Ctrl-C and SIGTERM still stop it, see
    `stop`). prctl is looked up here, in the parent: the child only calls it between fork and exec."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        prctl = ctypes.CDLL(None).prctl
    except (OSError, AttributeError):
        return None
    return lambda: prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def start_server(bind: str, web_port: int, grpc_port: int, log: Path,
                 timeout_s: float = START_TIMEOUT_S) -> tuple[subprocess.Popen, str]:
    """Start `rerun --serve-web --bind BIND` (no recording yet) and wait until both ports accept connections;
    returns the child and its gRPC address. ServeError (the child stopped) if it exits or is not up in
    time."""
    cmd = [str(rerun_executable()), "--serve-web", "--bind", bind, "--port", str(grpc_port),
           "--web-viewer-port", str(web_port)]
    # start_new_session: a terminal's Ctrl-C reaches bavo-view only, which stops it
    with open(log, "wb") as out:
        child = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                 start_new_session=True, preexec_fn=_die_with_parent())
    host = client_host(bind)
    deadline = time.monotonic() + timeout_s
    try:
        while not (_accepts(host, grpc_port) and _accepts(host, web_port)):
            if child.poll() is not None:
                tail = log.read_text(errors="replace")[-2000:]
                raise ServeError(f"rerun's server exited ({child.returncode}) before serving:\n{tail}")
            if time.monotonic() > deadline:
                raise ServeError(
                    f"rerun's server did not start listening on {bind}:{grpc_port} and {bind}:{web_port} "
                    f"within {timeout_s:.0f} s"
                )
            time.sleep(0.1)
    except BaseException:
        stop(child)
        raise
    name = f"[{host}]" if ":" in host else host
    return child, f"rerun+http://{name}:{grpc_port}/proxy"


def send_recording(rrd: Path, grpc_url: str, timeout_s: float | None = None) -> None:
    """Send the recording in `rrd` (with the default layout) to the server at `grpc_url`, from a child process
    (`python -m lerobot_bavo.viz.serve`) killed after `timeout_s` (default: `START_TIMEOUT_S` plus 1 s per
    MB): rerun's SDK can deadlock holding the GIL (see the module docstring), which no timer inside this
    process could interrupt. The child imports this very package (its folder leads its PYTHONPATH)."""
    import lerobot_bavo

    if timeout_s is None:
        timeout_s = START_TIMEOUT_S + Path(rrd).stat().st_size / 1e6
    package_root = str(Path(lerobot_bavo.__file__).resolve().parents[1])
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join(filter(None, [package_root, os.environ.get("PYTHONPATH")]))
    )
    cmd = [sys.executable, "-m", "lerobot_bavo.viz.serve", grpc_url, str(rrd)]
    try:
        done = subprocess.run(
            cmd, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout_s, env=env
        )
    except subprocess.TimeoutExpired:
        raise ServeError(f"sending {rrd} to rerun's server did not finish within {timeout_s:.0f} s") from None
    if done.returncode != 0:
        raise ServeError(
            f"sending {rrd} to rerun's server failed ({done.returncode}):\n{done.stderr[-2000:]}"
        )


def stop(child: subprocess.Popen, grace_s: float = 5.0) -> None:
    """Terminate the server child (SIGTERM, then SIGKILL after `grace_s`) and reap it."""
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(grace_s)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def _send(grpc_url: str, rrd: str) -> None:
    """The child of `send_recording`: connect as a gRPC client (before anything is logged), stream the
    file."""
    import rerun as rr
    from rerun.experimental import RrdReader, send_chunks

    from lerobot_bavo.viz.log import APPLICATION_ID, blueprint

    rec = rr.RecordingStream(APPLICATION_ID)
    rec.connect_grpc(grpc_url, default_blueprint=blueprint())
    send_chunks(RrdReader(rrd).stream(), recording=rec)
    rec.flush()
    rec.disconnect()


if __name__ == "__main__":
    _send(sys.argv[1], sys.argv[2])
