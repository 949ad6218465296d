"""The headless OpenGL context (EGL) and the two pieces of OpenGL state that moderngl does not expose.

Depth buffer. The renderer keeps a depth buffer only to decide which surface is in front; the depth it reports is
written exactly into a colour attachment (see ``_renderer.py``). For that decision to be as fine as float32 allows,
the depth buffer is a ``GL_DEPTH_COMPONENT32F`` renderbuffer and the clip-space depth is "reversed":
``glClipControl(GL_LOWER_LEFT, GL_ZERO_TO_ONE)`` with clip z = near and clip w = z gives the window depth near / z,
which is 1 at the near plane and tends to 0 at infinity (no far plane). A float stores near / z with a relative
error of 2^-24 at any depth, so two surfaces are told apart when their depths differ by more than about 1e-7 of
their depth (a 24-bit fixed-point buffer with the usual mapping resolves only z^2 / near * 2^-24). moderngl creates
24-bit depth renderbuffers and has no clip-control setter, so both are done here through the GL entry points that
``eglGetProcAddress`` returns.
"""

from __future__ import annotations

import ctypes

from depthguard.errors import RenderingError

# OpenGL enums (from the Khronos registry, gl.xml).
GL_RENDERBUFFER = 0x8D41
GL_FRAMEBUFFER = 0x8D40
GL_FRAMEBUFFER_COMPLETE = 0x8CD5
GL_DEPTH_COMPONENT32F = 0x8CAC
GL_LOWER_LEFT = 0x8CA1
GL_ZERO_TO_ONE = 0x935F

#: What to install when the context cannot be created (Debian / Ubuntu package names).
SYSTEM_PACKAGES_HINT = ("install the system packages libegl1 (libEGL.so.1, EGL loader and Mesa's EGL), libgl1 "
                        "(libGL.so.1) and libgl1-mesa-dri (Mesa's software rasteriser llvmpipe); ./dev.sh setup "
                        "installs them")


class GLContext:
    """A standalone moderngl context created through EGL (no display needed), plus the raw GL functions the
    renderer needs beyond moderngl. Make it current (``with context.ctx:``) before any call."""

    def __init__(self, libegl: str, libgl: str):
        try:
            import moderngl
        except ImportError as exc:  # pragma: no cover - moderngl is a dependency
            raise RenderingError(f"moderngl is not installed ({exc})") from None
        try:
            self.ctx = moderngl.create_standalone_context(backend="egl", libegl=libegl, libgl=libgl)
        except Exception as exc:  # glcontext raises a bare Exception naming what failed
            raise RenderingError(f"cannot create a headless OpenGL context through EGL (libegl={libegl!r}, "
                                 f"libgl={libgl!r}): {exc}; {SYSTEM_PACKAGES_HINT}") from None
        try:
            with self.ctx:
                self.renderer_name = str(self.ctx.info.get("GL_RENDERER", "?"))
                self._init_functions(libegl)
        except RenderingError:
            self.ctx.release()
            raise

    def _init_functions(self, libegl: str) -> None:
        if self.ctx.version_code < 450 and "GL_ARB_clip_control" not in self.ctx.extensions:
            raise RenderingError(f"OpenGL {self.ctx.version_code} on {self.renderer_name!r} lacks glClipControl "
                                 "(OpenGL 4.5 or GL_ARB_clip_control is needed)")
        egl = ctypes.CDLL(libegl)
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]

        def function(name, restype, *argtypes):
            address = egl.eglGetProcAddress(name.encode())
            if not address:
                raise RenderingError(f"eglGetProcAddress found no {name}")
            return ctypes.CFUNCTYPE(restype, *argtypes)(address)

        uint, sizei = ctypes.c_uint, ctypes.c_int
        self._clip_control = function("glClipControl", None, uint, uint)
        self._bind_renderbuffer = function("glBindRenderbuffer", None, uint, uint)
        self._renderbuffer_storage = function("glRenderbufferStorage", None, uint, uint, sizei, sizei)
        self._bind_framebuffer = function("glBindFramebuffer", None, uint, uint)
        self._check_framebuffer_status = function("glCheckFramebufferStatus", uint, uint)
        self._clip_control(GL_LOWER_LEFT, GL_ZERO_TO_ONE)

    def float_depth_renderbuffer(self, width: int, height: int):
        """A moderngl depth renderbuffer whose storage is re-specified as ``GL_DEPTH_COMPONENT32F``."""
        renderbuffer = self.ctx.depth_renderbuffer((width, height))
        self._bind_renderbuffer(GL_RENDERBUFFER, renderbuffer.glo)
        self._renderbuffer_storage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT32F, width, height)
        self._bind_renderbuffer(GL_RENDERBUFFER, 0)
        return renderbuffer

    def check_complete(self, framebuffer) -> None:
        """Raise :class:`RenderingError` unless ``framebuffer`` (moderngl) is complete."""
        self._bind_framebuffer(GL_FRAMEBUFFER, framebuffer.glo)
        status = self._check_framebuffer_status(GL_FRAMEBUFFER)
        self._bind_framebuffer(GL_FRAMEBUFFER, 0)  # every draw starts with moderngl's fbo.use(), which rebinds
        if status != GL_FRAMEBUFFER_COMPLETE:
            raise RenderingError(f"framebuffer incomplete (status 0x{status:x}) on {self.renderer_name!r}")

    def release(self) -> None:
        self.ctx.release()
