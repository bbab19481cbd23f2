"""MuJoCo model building (MjSpec), robot constants, kinematics/IK and lean offscreen rendering.

Headless EGL is the default GL backend (set before MuJoCo is first imported); override it by
exporting MUJOCO_GL yourself (e.g. `osmesa`).
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
