"""How jobs run: worker-process hygiene and exclusive locks shared by `bavo-eval` and `bavo-collect`."""

from lerobot_bavo.runtime.process import exclusive_lock, exit_with_parent, init_worker, limit_threads

__all__ = ["exclusive_lock", "exit_with_parent", "init_worker", "limit_threads"]
