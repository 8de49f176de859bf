"""Offscreen video of recorded runs (MuJoCo renderer, GIF via Pillow).

The GL backend is picked when mujoco is first imported: entry points that render set
``MUJOCO_GL=egl`` (unless the user chose ``osmesa``/``glfw``) before importing anything else.
Without any GL platform, :func:`render_gif` returns a message instead of raising.
"""

from __future__ import annotations

from pathlib import Path


def render_gif(run, path: Path, robot: int = 0, fps: int = 25, seconds: float = 4.0) -> str:
    """Render the last ``seconds`` of robot ``robot`` of a recorded run to a GIF; returns a status message.

    Args:
        run: any record with ``time`` (T,) [s] and ``qpos`` (T, B, 19) (MuJoCo generalized positions).
        path: output ``.gif``.
    """
    try:
        import mujoco
        from PIL import Image

        from dls_quadruped.robots.aliengo import constants as C

        model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
        data = mujoco.MjData(model)
        renderer = mujoco.Renderer(model, 360, 480)
    except Exception as err:  # no GL context (headless machine without EGL/OSMesa), or no Pillow
        return f"no offscreen renderer available ({err!r}); wrote the plot only"
    option = mujoco.MjvOption()
    option.geomgroup[:] = 1  # the robot's primitives live in the collision group (3)
    camera = mujoco.MjvCamera()
    camera.distance, camera.azimuth, camera.elevation = 1.6, 135.0, -20.0
    dt = float(run.time[1] - run.time[0])
    stride = max(1, int(round(1.0 / (fps * dt))))
    start = max(0, len(run.time) - int(seconds / dt))
    frames = []
    for k in range(start, len(run.time), stride):
        data.qpos[:] = run.qpos[k, robot]
        mujoco.mj_forward(model, data)
        camera.lookat[:] = data.qpos[:3]
        renderer.update_scene(data, camera, scene_option=option)
        frames.append(Image.fromarray(renderer.render()))
    renderer.close()
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return f"wrote {path} ({len(frames)} frames)"
