"""The camera renderer of the learner's observations: the cheapest robosuite offscreen settings that keep the task
visible, applied wherever frames are made for learning (training, evaluation, recorded and replayed demonstrations).

robosuite's scenes ask mujoco for a 4096 shadow map, reflections, a skybox and 4x multisampling in a 640 x 480
offscreen buffer. On a CPU (Mesa's llvmpipe through EGL) that made a 64 x 64 frame cost 59 ms (27 ms to draw,
32 ms to resolve and read the multisampled buffer). :func:`use_light_renderer` turns shadows, reflections, the skybox
and multisampling off and sizes the offscreen buffer to the images; the cube, the table, the line and the arm keep
their colours and the lighting, so everything the tasks need stays visible (``docs/results/camera_speed.md`` shows both
renderers' frames side by side). Evaluation videos of state runs keep robosuite's full renderer.

It also frees each context safely. robosuite frees an offscreen context when the context is collected, and mujoco
frees the context's buffers and textures in whichever GL context is current at that moment: every context of the
same scene numbers its objects alike, so collecting one env's context deleted the textures of the env rendering then,
and robosuite's GL context release left no context current at all, so that a frame read next was uninitialised
memory. :func:`adopt_renderer` gives a sim's context :class:`OwnContextRenderer`'s release, which frees it in its own
GL context and then makes current again the context that was current before; :func:`release_renderer` does so
at once (``RobosuiteEnv.close``).
"""
from __future__ import annotations

import os
import sys
import weakref

# robosuite picks its GL backend once, when it is first imported; EGL renders headless on the CPU (Mesa),
# osmesa does not work with this stack.
os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
from robosuite.utils.binding_utils import MjRenderContextOffscreen  # noqa: E402

#: The camera renderers of :class:`~torchrl_mpail2.envs.robosuite_env.RobosuiteEnv`: ``light`` (this module's) and
#: ``full`` (robosuite's own settings).
RENDERERS = ("light", "full")
#: Scene flags the light renderer turns off.
HEAVY_SCENE_FLAGS = (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX)


def check_renderer(renderer: str) -> None:
    """Raises a ``ValueError`` naming the valid renderers when ``renderer`` is not one of :data:`RENDERERS`."""
    if renderer not in RENDERERS:
        raise ValueError(f"unknown renderer {renderer!r}; valid renderers: {', '.join(RENDERERS)}")


#: The GL context :func:`make_renderer_current` made current last (a weak reference), made current again after a
#: release.
_claimed: weakref.ref | None = None


class OwnContextRenderer(MjRenderContextOffscreen):
    """robosuite's offscreen context, released in its own GL context (:func:`release_renderer`) when collected."""

    def __del__(self):
        _release(self)


def _release(context) -> None:
    """Frees ``context``'s mujoco buffers and its GL context with that GL context current, then makes current again
    the GL context that was current before, if it was another one. Idempotent."""
    gl_ctx = getattr(context, "gl_ctx", None)
    if gl_ctx is None:
        return
    restore = _restorer(gl_ctx)
    try:
        gl_ctx.make_current()
        context.con.free()
        gl_ctx.free()  # robosuite's: also releases whatever context this thread had current
    except Exception:  # noqa: BLE001 - at interpreter exit the GL library may be gone already; nothing to keep
        pass
    context.gl_ctx = None
    if restore is not None:
        try:
            restore()
        except Exception:  # noqa: BLE001 - the context to restore was freed meanwhile; the next claim sets one
            pass


def _restorer(freed):
    """A function that makes current again the GL context current now, or ``None`` when that is ``freed`` or none.
    EGL (``MUJOCO_GL=egl``) is asked for its current context; other backends restore the one claimed last."""
    egl = sys.modules.get("robosuite.renderers.context.egl_context")
    if egl is not None and isinstance(freed, egl.EGLGLContext):
        current = egl.EGL.eglGetCurrentContext()
        if not current or (freed._context and current.address == freed._context.address):
            return None
        return lambda: egl.EGL.eglMakeCurrent(egl.EGL_DISPLAY, egl.EGL.EGL_NO_SURFACE, egl.EGL.EGL_NO_SURFACE, current)
    claimed = _claimed() if _claimed is not None else None
    return None if claimed is None or claimed is freed else claimed.make_current


def adopt_renderer(sim) -> None:
    """Gives ``sim``'s offscreen context (robosuite's ``MjRenderContextOffscreen``), if it has one,
    :class:`OwnContextRenderer`'s release, so that collecting it never touches another env's GL objects."""
    context = sim._render_context_offscreen
    if context is not None and type(context) is MjRenderContextOffscreen:
        context.__class__ = OwnContextRenderer


def release_renderer(sim) -> None:
    """Frees ``sim``'s offscreen context now, in its own GL context (see :func:`adopt_renderer`); the GL context
    claimed last stays current. Nothing happens when ``sim`` has no context or it was released already."""
    context = sim._render_context_offscreen
    if context is not None:
        _release(context)


def make_renderer_current(sim) -> None:
    """Makes ``sim``'s offscreen GL context the current one, if it has one. robosuite renders into whichever context
    was made current last, i.e. the newest env's: with a training and an evaluation env in one process, each must
    claim its own before it renders (their buffers may differ, e.g. after a larger video frame)."""
    global _claimed
    context = sim._render_context_offscreen
    if context is not None:
        adopt_renderer(sim)
        context.gl_ctx.make_current()
        _claimed = weakref.ref(context.gl_ctx)


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
