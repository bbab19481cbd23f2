"""Screenshot of a running `bavo-view --web` in headless Chromium (Debian's `chromium` package).

`chromium --headless --screenshot` captures at the page's load event, before rerun's web viewer has
fetched its WebAssembly bundle and the recording; this script opens the page with the DevTools
protocol instead, waits, and captures then. Rendering is software (SwiftShader WebGL).

    bavo-view --rrd outputs/eval/x/videos/cube_handoff_stage_seed1000.rrd --web &
    python scripts/view_screenshot.py --output docs/view/bavo_view.png --wait 60
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]


async def _capture(ws_url: str, wait: float, width: int, height: int) -> bytes:
    import aiohttp

    async with aiohttp.ClientSession() as session, session.ws_connect(ws_url, max_msg_size=0) as ws:
        ident = 0

        async def call(method: str, **params):
            nonlocal ident
            ident += 1
            await ws.send_str(json.dumps({"id": ident, "method": method, "params": params}))
            async for msg in ws:
                data = json.loads(msg.data)
                if data.get("id") == ident:
                    if "error" in data:
                        raise RuntimeError(f"{method}: {data['error']}")
                    return data["result"]
            raise RuntimeError("DevTools connection closed")

        await call(
            "Emulation.setDeviceMetricsOverride",
            width=width,
            height=height,
            deviceScaleFactor=1,
            mobile=False,
        )
        await asyncio.sleep(wait)
        shot = await call("Page.captureScreenshot", format="png")
        return base64.b64decode(shot["data"])


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--url", default="http://localhost:9090/?url=rerun%2Bhttp://127.0.0.1:9876/proxy",
                   help="the web viewer's address (bavo-view --web prints it)")
    p.add_argument("--output", type=Path, required=True)
    p.add_argument("--wait", type=float, default=60.0, help="seconds to let the viewer load and render")
    p.add_argument("--width", type=int, default=1600)
    p.add_argument("--height", type=int, default=1000)
    p.add_argument("--port", type=int, default=9222, help="DevTools port")
    args = p.parse_args(argv)
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        raise SystemExit("chromium not found: apt-get install chromium")
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.Popen(
            [
                exe,
                *FLAGS,
                f"--user-data-dir={profile}",
                f"--remote-debugging-port={args.port}",
                f"--window-size={args.width},{args.height}",
                args.url,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.time() + 30
            while True:
                try:
                    pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{args.port}/json", timeout=2))
                    page = next(x for x in pages if x.get("type") == "page")
                    break
                except (OSError, StopIteration):
                    if time.time() > deadline:
                        raise SystemExit("chromium's DevTools endpoint did not come up") from None
                    time.sleep(0.5)
            png = asyncio.run(_capture(page["webSocketDebuggerUrl"], args.wait, args.width, args.height))
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_bytes(png)
    print(f"wrote {args.output} ({len(png)} bytes)")


if __name__ == "__main__":
    main()
