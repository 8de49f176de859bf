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
    return render_gif_row([run], path, robot=robot, fps=fps, seconds=seconds)


def render_gif_row(runs: list, path: Path, robot: int = 0, fps: int = 25, seconds: float = 4.0,
                   labels: list[str] | None = None, size: tuple[int, int] = (360, 480)) -> str:
    """Render the same time window of robot ``robot`` of several runs side by side (one panel per run,
    ``labels`` written on top) to one GIF; returns a status message. Runs share their time step."""
    try:
        import mujoco
        from PIL import Image, ImageDraw

        from dls_quadruped.robots.aliengo import constants as C

        model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
        data = mujoco.MjData(model)
        renderer = mujoco.Renderer(model, *size)
    except Exception as err:  # noqa: BLE001 -- no GL context (headless machine without EGL/OSMesa), or no Pillow
        return f"no offscreen renderer available ({err!r}); wrote the plot only"
    option = mujoco.MjvOption()
    option.geomgroup[:] = 1  # the robot's primitives live in the collision group (3)
    camera = mujoco.MjvCamera()
    camera.distance, camera.azimuth, camera.elevation = 1.6, 135.0, -20.0
    length = min(len(r.time) for r in runs)
    dt = float(runs[0].time[1] - runs[0].time[0])
    stride = max(1, round(1.0 / (fps * dt)))
    start = max(0, length - int(seconds / dt))
    frames = []
    for k in range(start, length, stride):
        panels = []
        for i, run in enumerate(runs):
            data.qpos[:] = run.qpos[k, robot]
            mujoco.mj_forward(model, data)
            camera.lookat[:] = data.qpos[:3]
            renderer.update_scene(data, camera, scene_option=option)
            img = Image.fromarray(renderer.render())
            if labels:
                ImageDraw.Draw(img).text((8, 8), labels[i], fill=(255, 255, 255))
            panels.append(img)
        frame = Image.new("RGB", (size[1] * len(panels), size[0]))
        for i, img in enumerate(panels):
            frame.paste(img, (size[1] * i, 0))
        frames.append(frame)
    renderer.close()
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return f"wrote {path} ({len(frames)} frames, {len(runs)} panels)"
