"""A still of any scene with its arms in a working pose, and a text summary of what the scene holds."""

from __future__ import annotations

import mujoco
import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.arm import Arm
from dvrl_marl.rendering import SceneRenderer
from dvrl_marl.scene import load_model

__all__ = ["scene_arms", "render_scene", "scene_summary"]

#: Preview tip positions (world, metres) per arm prefix; other arms go to their workspace default.
_PREVIEW_TIPS = {
    "suction/": (-0.03, 0.0, 0.034),
    "grasper/": (0.028, 0.006, 0.05),
    "psm/": (0.0, 0.0, 0.03),
}


def scene_arms(model: mujoco.MjModel) -> dict[str, str]:
    """Arm prefix -> tool name, found from the bodies named ``<prefix>rcm``."""
    arms = {}
    for body in range(model.nbody):
        name = model.body(body).name
        if name.endswith("rcm"):
            prefix = name[: -len("rcm")]
            has_roll = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}tool_roll") >= 0
            arms[prefix] = kinematics.LND.name if has_roll else kinematics.SUCTION_IRRIGATION.name
    return arms


def renderable_scenes() -> list[str]:
    """The scenes with an endoscope camera; the others (``common``, the robot files) are parts the scenes include."""
    from dvrl_marl.assets import scenes_dir

    return sorted(path.stem for path in scenes_dir().glob("*.xml") if 'name="endoscope"' in path.read_text())


def render_scene(name: str, width: int = 640, height: int = 480) -> np.ndarray:
    """RGB image (height, width, 3) of scene ``name`` from its endoscope camera, arms in a working pose."""
    model = load_model(name)
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "endoscope") < 0:
        raise ValueError(f"scene {name!r} has no endoscope camera: it is a part that scenes include; renderable "
                         f"scenes: {renderable_scenes()}")
    # the offscreen framebuffer made as large as the image (the scenes' is 1920 x 1080); past what the OpenGL can
    # draw, the renderer says so
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, int(width))
    model.vis.global_.offheight = max(model.vis.global_.offheight, int(height))
    data = mujoco.MjData(model)
    for prefix, tool in scene_arms(model).items():
        arm = Arm(model, data, prefix, tool)
        tip = arm.to_base(_PREVIEW_TIPS.get(prefix, _PREVIEW_TIPS["psm/"]))
        arm.set_tip(*tip.tolist())
        if arm.tool.has_jaw:
            arm.set_jaw(0.6)
    renderer = SceneRenderer(model, data, "rgb_array", width=width, height=height)
    try:
        return renderer.render()
    finally:
        renderer.close()


def scene_summary(name: str) -> str:
    """Human-readable summary: size of the model, arms and their joints, cameras, sites."""
    model = load_model(name)
    lines = [
        f"scene {name!r}",
        f"  bodies {model.nbody}, joints {model.njnt}, dofs {model.nv}, geoms {model.ngeom}, timestep {model.opt.timestep} s",
    ]
    for prefix, tool in scene_arms(model).items():
        joints = ", ".join(kinematics.get_tool(tool).joint_names)
        lines.append(f"  arm {prefix!r}: {tool} PSM ({joints})")
    cameras = [model.camera(i).name for i in range(model.ncam)]
    lines.append(f"  cameras: {', '.join(cameras)}")
    sites = [model.site(i).name for i in range(model.nsite) if "/" not in model.site(i).name]
    if sites:
        lines.append(f"  task sites: {', '.join(sites)}")
    return "\n".join(lines)
