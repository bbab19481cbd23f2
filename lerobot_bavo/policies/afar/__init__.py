"""A-FAR policy for LeRobot 0.6.1, registered as policy type "afar"."""

from .configuration_afar import AfarConfig
from .modeling_afar import AfarPolicy
from .processor_afar import make_afar_pre_post_processors

__all__ = ["AfarConfig", "AfarPolicy", "make_afar_pre_post_processors"]
