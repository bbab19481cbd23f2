"""Plugin shim: LeRobot's CLIs import every installed `lerobot_env_*` distribution by name.

It registers the gym ids, the `bavo` EnvConfig and the policy configs (`lerobot_bavo.register_lerobot_types`;
`import lerobot_bavo` alone registers only the gym ids). The CLIs (and only they, since only they import this
module) also get the in-memory sample loading of BAVO training views (`lerobot_bavo.datasets.fast`; opt out
with BAVO_FAST_DATASET=0).
"""

from lerobot_bavo import register_lerobot_types
from lerobot_bavo.datasets.fast import install_lerobot_train_hook

register_lerobot_types()
install_lerobot_train_hook()
