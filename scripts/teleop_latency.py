"""Key-press-to-next-frame latency of `bavo-teleop`, measured in the page, and the docs/teleop.md screenshot.

Starts `bavo-teleop` (default observation settings: 240 x 320 active image, 256 points) on
127.0.0.1 with a throw-away dataset, opens the page in headless Chromium (Debian's `chromium`,
driven by playwright), starts an episode and presses keys at irregular intervals. The page
timestamps each key press (`performance.now()`) and, when the first frame rendered from a tick
that used that input has been drawn (the frame header acknowledges the input's sequence number;
the time is taken in the next `requestAnimationFrame`), records the difference.

    python scripts/teleop_latency.py [--presses 60] [--task cube_handoff] [--screenshot docs/teleop.png]
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_teleop import CHROMIUM, hold, open_page, start_server  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presses", type=int, default=60)
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--screenshot", type=Path, default=None, help="save a screenshot of the page here (PNG)")
    args = ap.parse_args()
    if CHROMIUM is None:
        print("needs Debian's chromium", file=sys.stderr)
        return 2
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_server(Path(tmp) / "ds", "--seed", "100000")
        try:
            with sync_playwright() as p:
                ctx, page = open_page(p, url, Path(tmp) / "profile")
                page.keyboard.press("n")
                page.wait_for_function("window.bavo.status.state === 'running'", timeout=60000)
                rng = random.Random(0)
                # a small demonstration while measuring: camera look-at and a few arm moves
                script = (
                    ["3", "l"] + ["a"] * 6 + ["2"] + ["d"] * 8 + ["r"] * 4 + ["w"] * 6 + ["1"] + ["d"] * 8
                )
                for k in range(args.presses):
                    key = script[k % len(script)]
                    if key in ("1", "2", "3", "l"):
                        page.keyboard.press(key)
                    else:
                        hold(page, key, rng.uniform(0.08, 0.2))
                    time.sleep(rng.uniform(0.05, 0.2))
                time.sleep(0.5)
                lat = np.array(page.evaluate("window.bavo.latencies"))
                header = page.evaluate("window.bavo.lastHeader")
                if args.screenshot is not None:
                    args.screenshot.parent.mkdir(parents=True, exist_ok=True)
                    page.screenshot(path=str(args.screenshot))
                page.keyboard.press("Backspace")
                ctx.close()
        finally:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=120)
    out = {"presses": len(lat), "median_ms": round(float(np.median(lat)), 1),
           "p90_ms": round(float(np.percentile(lat, 90)), 1), "max_ms": round(float(lat.max()), 1),
           "mean_ms": round(float(lat.mean()), 1), "control_hz": header.get("control_hz"),
           "tick_overruns": header.get("overruns"), "steps": header.get("tick")}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
