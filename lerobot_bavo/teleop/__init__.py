"""Human demonstrations by browser teleoperation (`bavo-teleop`), recorded as BAVO datasets.

- `controls`: operator input -> end-effector targets -> joint targets through our IK (pure, deterministic).
- `session`: the operator as an agent of the dataset recorder, input logs and their replay, the dataset
  writer.
- `protocol`: the page's messages, each checked whole into a small typed value (pure).
- `access`: who may connect: the Host / Origin checks and the per-run token (pure).
- `server`: the web server (aiohttp) and the `bavo-teleop` CLI; `static/` holds the page.
"""

from lerobot_bavo.teleop.controls import CONTROLS_HELP, TeleopController, TickInput

__all__ = ["CONTROLS_HELP", "TeleopController", "TickInput"]
