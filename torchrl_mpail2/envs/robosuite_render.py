"""The camera renderer of the learner's observations: the cheapest robosuite offscreen settings that keep the task
visible, applied wherever frames are made for learning (training, evaluation, recorded and replayed demonstrations).

robosuite's scenes ask mujoco for a 4096 shadow map, reflections, a skybox and 4x multisampling in a 640 x 480
offscreen buffer. On a CPU (Mesa's llvmpipe through EGL) that made a 64 x 64 frame cost 59 ms (27 ms to draw,
32 ms to resolve and read the multisampled buffer). :func:`use_light_renderer` turns shadows, reflections, the skybox
and multisampling off and sizes the offscreen buffer to the images; the cube, the table, the line and the arm keep
their colours and the lighting, so everything the tasks need stays visible (``docs/cameras.md`` shows both
renderers' frames side by side). Evaluation videos of state runs keep robosuite's full renderer.
"""
from __future__ import annotations

import mujoco

#: The camera renderers of :class:`~torchrl_mpail2.envs.robosuite_env.RobosuiteEnv`: ``light`` (this module's) and
#: ``full`` (robosuite's own settings).
RENDERERS = ("light", "full")
#: Scene flags the light renderer turns off.
HEAVY_SCENE_FLAGS = (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX)


def check_renderer(renderer: str) -> None:
    """Raises a ``ValueError`` naming the valid renderers when ``renderer`` is not one of :data:`RENDERERS`."""
    if renderer not in RENDERERS:
        raise ValueError(f"unknown renderer {renderer!r}; valid renderers: {', '.join(RENDERERS)}")


def make_renderer_current(sim) -> None:
    """Makes ``sim``'s offscreen GL context the current one, if it has one. robosuite renders into whichever context
    was made current last, i.e. the newest env's: with a training and an evaluation env in one process, each must
    claim its own before it renders (their buffers may differ, e.g. after a larger video frame)."""
    context = sim._render_context_offscreen
    if context is not None:
        context.gl_ctx.make_current()


def use_light_renderer(sim, image_size: int) -> None:
    """Rebuilds ``sim``'s offscreen rendering context (robosuite's ``MjRenderContextOffscreen``) without
    multisampling, with an ``image_size`` square buffer and with shadows, reflections and the skybox off.

    The context must already exist (robosuite makes it at construction when ``has_offscreen_renderer``); mujoco
    reads ``offsamples`` and the buffer size only when a context is created, hence the rebuild. A later render larger
    than the buffer grows it (robosuite's own rule); the other settings stay.

    Args:
        sim: robosuite's ``MjSim`` (``env.sim``).
        image_size: side of the camera images, pixels.

    Raises:
        RuntimeError: when ``sim`` has no offscreen context.
    """
    context = sim._render_context_offscreen
    if context is None:
        raise RuntimeError("use_light_renderer: the simulation has no offscreen renderer (has_offscreen_renderer=False)")
    vis = sim.model._model.vis
    vis.quality.offsamples = 0
    vis.global_.offwidth = vis.global_.offheight = int(image_size)
    make_renderer_current(sim)
    context.con.free()
    context._set_mujoco_context_and_buffers()
    for flag in HEAVY_SCENE_FLAGS:
        context.scn.flags[flag] = 0
