"""The BAVO world: table, lights, third-person camera and the three arms, built with MjSpec.

Task objects are added by each task's `build(spec)`; the benchmark occluder is added
only for conditions that use it, so a Clean model contains no occluder at all.
"""

from __future__ import annotations

import mujoco

from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.robot import add_camera_arm, add_manipulator
from lerobot_bavo.sim.transforms import look_at_quat

# Third-person view from behind and above the operator side (the camera arm's side), so that
# left/right in the video match left/right in the active view.
THIRD_PERSON_POS = (0.42, -0.95, 1.05)
THIRD_PERSON_TARGET = (0.0, 0.05, 0.0)


def build_base_spec(fovy: float = C.ACTIVE_CAMERA_FOVY) -> mujoco.MjSpec:
    """A fresh spec with physics options, the table, lights, cameras and all three arms."""
    spec = mujoco.MjSpec()
    spec.modelname = "bavo"
    spec.compiler.degree = False  # all angles in this package are radians
    opt = spec.option
    opt.timestep = C.PHYSICS_DT
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.impratio = 100.0
    opt.noslip_iterations = 3
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    # CPU (llvmpipe) rendering budget: no shadow pass, no multisampling (4x MSAA alone more than
    # doubles the cost of a 240x320 frame, and it would blend depth across object edges), and
    # coarser tessellation of round primitives. Measured in benchmarks/env_step.py.
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.visual.quality.numslices = 12
    spec.visual.quality.numstacks = 6
    spec.visual.map.znear = 0.01
    spec.visual.map.zfar = 20.0
    spec.stat.extent = 1.0
    spec.stat.center = [0, 0, 0.2]

    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.75, 0.8, 0.85],
        rgb2=[0.35, 0.4, 0.45],
        width=64,
        height=64,
    )
    world = spec.worldbody
    world.add_light(
        name="key",
        pos=[0, -0.3, 2.5],
        dir=[0, 0.1, -1],
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        castshadow=False,
        diffuse=[0.7, 0.7, 0.7],
        specular=[0.1, 0.1, 0.1],
    )
    world.add_light(
        name="fill",
        pos=[0.8, 1.2, 1.5],
        dir=[-0.4, -0.6, -0.7],
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
        castshadow=False,
        diffuse=[0.35, 0.35, 0.35],
        specular=[0, 0, 0],
    )
    spec.visual.headlight.ambient = [0.3, 0.3, 0.3]
    spec.visual.headlight.diffuse = [0.2, 0.2, 0.2]

    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3, 3, 0.1], pos=[0, 0, -0.75],
                   rgba=[0.55, 0.55, 0.5, 1], group=C.GROUP_WORLD)
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(C.TABLE_HALF_SIZE),
                   pos=[0, 0, C.TABLE_CENTER_Z], rgba=[0.72, 0.62, 0.5, 1], group=C.GROUP_WORLD,
                   friction=[1.0, 0.01, 0.001])
    for sx in (-1, 1):
        for sy in (-1, 1):
            world.add_geom(name=f"table_leg_{sx:+d}{sy:+d}", type=mujoco.mjtGeom.mjGEOM_BOX,
                           size=[0.03, 0.03, 0.325], pos=[sx * 0.55, sy * 0.31, -0.525],
                           rgba=[0.4, 0.35, 0.3, 1], group=C.GROUP_WORLD, contype=0, conaffinity=0)

    world.add_camera(name=C.THIRD_PERSON_CAMERA, pos=list(THIRD_PERSON_POS),
                     quat=list(look_at_quat(THIRD_PERSON_POS, THIRD_PERSON_TARGET)), fovy=55)

    add_manipulator(spec, C.LEFT_MOUNT)
    add_manipulator(spec, C.RIGHT_MOUNT)
    add_camera_arm(spec, fovy=fovy)
    return spec


OCCLUDER_BODY = "occluder"


def panel_geom_name(body_name: str) -> str:
    """The box geom of a panel body (the occluder's, a decoy's): `<body>_geom`."""
    return f"{body_name}_geom"


OCCLUDER_GEOM = panel_geom_name(OCCLUDER_BODY)


def add_occluder(spec: mujoco.MjSpec, half_extents) -> None:
    """The benchmark occluder: a mocap panel in its own geom group with no collision at all.

    It is a purely visual obstacle (contype = conaffinity = 0), so it never pushes objects or
    arms; counterfactual renders drop its group (`GROUP_OCCLUDER`). Only occluded conditions
    build it.
    """
    _add_panel(spec, OCCLUDER_BODY, half_extents, pos=[0, 0, 1.0])


# Decoy panels (`BavoEnv(decoy_panels=...)`, a data-collection lever): copies of the occluder that never
# hide the current target. Named `decoy_panel_<i>` (geom: `panel_geom_name`), parked at `DECOY_PARKED_POS`
# (below the floor, out of every view) until placed.
DECOY_BODY_PREFIX = "decoy_panel"
DECOY_PARKED_POS = (0.0, 0.0, -2.0)


def decoy_body_name(index: int) -> str:
    return f"{DECOY_BODY_PREFIX}_{index}"


def add_decoy_panels(spec: mujoco.MjSpec, half_extents, count: int) -> None:
    """`count` decoy panels: the occluder's size, colour, geom group and (absent) collision, so that in an
    observation a decoy looks exactly like the occluder. In `GROUP_OCCLUDER`, so the privileged visibility
    renders drop them as they drop the occluder: V and CVG measure the benchmark occluder alone."""
    for i in range(count):
        _add_panel(spec, decoy_body_name(i), half_extents, pos=list(DECOY_PARKED_POS))


def _add_panel(spec: mujoco.MjSpec, body_name: str, half_extents, pos) -> None:
    body = spec.worldbody.add_body(name=body_name, mocap=True, pos=pos)
    body.add_geom(name=panel_geom_name(body_name), type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half_extents),
                  rgba=[0.16, 0.42, 0.46, 1], group=C.GROUP_OCCLUDER, contype=0, conaffinity=0, mass=0.1)
