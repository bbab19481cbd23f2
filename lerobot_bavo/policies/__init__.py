"""LeRobot policy plugins of lerobot-bavo: "maniflow" and "afar".

Importing this package registers both policy types with LeRobot's `PreTrainedConfig` registry (draccus raises
ValueError when a name is registered twice; Python's module cache makes repeated imports harmless, and the
config modules are only ever imported under their package path). LeRobot's factory then resolves
`ManiFlowPolicy` / `AfarPolicy` and `make_{maniflow,afar}_pre_post_processors` by module naming convention
(`configuration_*` -> `modeling_*` / `processor_*`).
"""

from .afar import AfarConfig, AfarPolicy, make_afar_pre_post_processors
from .maniflow import ManiFlowConfig, ManiFlowPolicy, make_maniflow_pre_post_processors

__all__ = [
    "AfarConfig",
    "AfarPolicy",
    "ManiFlowConfig",
    "ManiFlowPolicy",
    "make_afar_pre_post_processors",
    "make_maniflow_pre_post_processors",
]
