"""ManiFlow policy for LeRobot 0.6.1, registered as policy type "maniflow"."""

from .configuration_maniflow import ManiFlowConfig
from .modeling_maniflow import ManiFlowPolicy
from .processor_maniflow import make_maniflow_pre_post_processors

__all__ = ["ManiFlowConfig", "ManiFlowPolicy", "make_maniflow_pre_post_processors"]
