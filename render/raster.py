"""The per-frame rasteriser: background, grid ground with the characters' shadow, root trajectory
and key markers, the characters (and optional key ghosts), read back as RGBA.

The background and the ground are single-sampled (nothing in them has an edge that MSAA would
smooth: the ground's grid lines are filtered in the shader and its rim is faded out, so each
of their pixels is what the 4 samples of the MSAA buffer held); the trajectory, key marks and
characters go into the 4x MSAA buffer with premultiplied alpha, only inside the screen
rectangle they cover, which is then resolved and laid over them (``shaders.COMPOSITE_FS``).
On llvmpipe the frame's cost follows the samples written, so this is about half the work of
drawing everything multisampled."""

from __future__ import annotations

import ctypes

import numpy as np

from render import shaders
from render.culling import Runs
from render.geometry import Geometry
from render.gl import RenderError, context

CLAY = (0.62, 0.50, 0.38)  # linear albedo of the filled character
BLOCKING_CLAY = (0.40, 0.47, 0.60)  # the stepped-keys character, so the panels cannot be confused
GHOST = (0.35, 0.75, 1.0)
EVERY_FRAME = 3.0e38  # a trail's reach (frames) that draws every frame: a float32 GL takes
#: (past, future) RGBA of the body paths, then of the key marks
OVERLAY_COLORS = (
    ((1.0, 0.78, 0.25, 0.95), (0.85, 0.85, 0.9, 0.35)),
    ((1.0, 0.45, 0.15, 1.0), (1.0, 0.45, 0.15, 0.55)),
)
KEY_DIR = np.array([0.45, 0.80, 0.40]) / np.linalg.norm([0.45, 0.80, 0.40])
FILL_DIR = np.array([-0.6, 0.35, -0.3]) / np.linalg.norm([-0.6, 0.35, -0.3])


def _gil_free_finish(ctx):
    """``glFinish`` called through ctypes, which lets go of the GIL while llvmpipe's threads
    rasterise (moderngl holds it for the whole wait), so the review's writer thread can burn
    in, encode and write the previous frames meanwhile. Falls back to ``ctx.finish``."""

    try:
        egl = ctypes.CDLL("libEGL.so.1")
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        addr = egl.eglGetProcAddress(b"glFinish")
        if addr:
            return ctypes.CFUNCTYPE(None)(addr)
    except OSError:
        pass
    return ctx.finish


class MeshSet:
    """GPU buffers for a list of geometries; ``upload(i)`` writes frame ``i``'s points."""

    def __init__(self, ctx, mesh_prog, shadow_prog, geoms: list[Geometry]):
        self.geoms, self.items, self._all = geoms, [], None
        for g in geoms:
            vbo = ctx.buffer(reserve=g.n_points * 12, dynamic=True)
            ibo = ctx.buffer(np.ascontiguousarray(g.tris, np.int32).tobytes())
            attrs = [(vbo, "3f", "in_pos")]
            nbo = None
            if g.smooth:
                nbo = ctx.buffer(reserve=g.n_points * 12, dynamic=True)
                attrs.append((nbo, "3f", "in_nrm"))
            vao = ctx.vertex_array(mesh_prog, attrs, index_buffer=ibo, index_element_size=4)
            svao = ctx.vertex_array(
                shadow_prog, [(vbo, "3f", "in_pos")], index_buffer=ibo, index_element_size=4
            )
            self.items.append((g, vbo, nbo, vao, svao))

    @property
    def n_frames(self) -> int:
        return self.geoms[0].n_frames if self.geoms else 0

    def upload(self, i: int) -> list[np.ndarray]:
        """Writes frame ``i`` and returns its points (one (N, 3) array per geometry)."""
        points = []
        for g, vbo, nbo, _, _ in self.items:
            pts, nrm = g.frame(i)
            vbo.write(np.ascontiguousarray(pts, np.float32))
            if nbo is not None:
                nbo.write(np.ascontiguousarray(nrm, np.float32))
            points.append(pts)
        return points

    def all_points(self) -> np.ndarray:
        """Every frame's points, (n, 3) (for the few frames of the key ghosts)."""
        if self._all is None:
            self._all = np.concatenate(
                [np.asarray(g.frame(i)[0], np.float64) for g in self.geoms for i in range(g.n_frames)]
            ).reshape(-1, 3)
        return self._all

    def draw(self, prog, shadow=False):
        for g, _, _, vao, svao in self.items:
            if shadow:
                svao.render()
            else:
                prog["use_flat"].value = int(not g.smooth)
                vao.render()

    def release(self):
        for _, vbo, nbo, vao, svao in self.items:
            for o in (vao, svao, vbo, nbo):
                if o is not None:
                    o.release()


def _ribbon(path: np.ndarray, y: float, width: float) -> np.ndarray:
    """Triangles (as a flat (N, 4) array of x, y, z, frame) of a ground ribbon along ``path``:
    two a segment, frame by frame."""
    p = path[:, [0, 2]].astype(np.float64)
    d = np.gradient(p, axis=0) if len(p) > 1 else np.zeros_like(p)
    n = np.stack([-d[:, 1], d[:, 0]], 1)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
    sides = np.stack([p + n * width / 2, p - n * width / 2])  # (2, N, 2): the left and right edges
    side, step = (
        np.array([0, 1, 0, 1, 1, 0]),
        np.array([0, 0, 1, 0, 1, 1]),
    )  # (a_i, b_i, a_i+1), (b_i, b_i+1, a_i+1)
    frame = np.arange(len(p) - 1)[:, None] + step  # (N - 1, 6)
    xz = sides[side, frame].reshape(-1, 2)
    return np.stack([xz[:, 0], np.full(len(xz), y), xz[:, 1], frame.ravel()], 1).astype(np.float32)


def _discs(centers: np.ndarray, y: float, r_in: float, r_out: float, t: np.ndarray, seg=20) -> np.ndarray:
    """Flat rings (r_in > 0) or discs on the ground, as (N, 4) x, y, z, frame triangles."""
    th = np.linspace(0, 2 * np.pi, seg + 1)
    unit = np.stack([np.cos(th), np.sin(th)], 1)  # (seg + 1, 2)
    c = np.asarray(centers, np.float64).reshape(-1, 3)[:, None, [0, 2]]
    rims = np.stack([c + r_out * unit, c + r_in * unit], 1)  # (K, 2, seg + 1, 2): outer, inner
    rim, step = (
        np.array([0, 0, 1, 0, 1, 1]),
        np.array([0, 1, 1, 0, 1, 0]),
    )  # (o_k, o_k+1, i_k+1), (o_k, i_k+1, i_k)
    pts = rims[:, rim, np.arange(seg)[:, None] + step].reshape(-1, 2)
    tt = np.repeat(np.asarray(t, np.float64), seg * 6)
    return np.stack([pts[:, 0], np.full(len(pts), y), pts[:, 1], tt], 1).astype(np.float32)


def screen_rect(vp: np.ndarray, viewport, points: list[np.ndarray], pad: int = 2):
    """The scissor rectangle (x, y, w, h, GL window pixels) inside ``viewport`` that holds every
    triangle with corners in ``points`` (world (N, 3) arrays) under the view-projection ``vp``
    (4x4, column vectors); None when nothing is on screen. A triangle whose corners are all in
    front of the eye projects inside their projections' box; when one is not, the whole viewport."""
    pts = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for p in points])
    x0, y0, vw, vh = viewport
    if not len(pts):
        return None
    m = np.asarray(vp, np.float64)
    clip = pts @ m[:, :3].T + m[:, 3]
    wc = clip[:, 3]
    if not np.all(wc > 1e-9):
        return tuple(int(v) for v in viewport)
    sx = x0 + (clip[:, 0] / wc + 1.0) * 0.5 * vw
    sy = y0 + (clip[:, 1] / wc + 1.0) * 0.5 * vh
    lx, hx = max(int(np.floor(sx.min())) - pad, x0), min(int(np.ceil(sx.max())) + pad, x0 + vw)
    ly, hy = max(int(np.floor(sy.min())) - pad, y0), min(int(np.ceil(sy.max())) + pad, y0 + vh)
    if hx <= lx or hy <= ly:
        return None
    return lx, ly, hx - lx, hy - ly


class Renderer:
    """Renders frames of ``size`` (w, h) split into ``panels`` side by side."""

    def __init__(self, size: tuple[int, int], panels: int = 1, samples: int = 4):
        import moderngl

        self.mgl = moderngl
        ctx = self.ctx = context()
        w, h = size
        if w < 16 or h < 16 or w % 2 or h % 2:
            raise RenderError(f"image size {w}x{h}: width and height must be even and at least 16")
        self.size, self.panels = (w, h), panels
        max_samples = ctx.info.get("GL_MAX_SAMPLES", 4)
        samples = min(samples, max_samples)
        self.samples = samples
        self.layer = ctx.texture((w, h), 4, samples=samples)
        self.msaa = ctx.framebuffer(
            color_attachments=[self.layer], depth_attachment=ctx.depth_renderbuffer((w, h), samples=samples)
        )
        self.image = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), 4)])
        self.mask_tex = ctx.texture((w, h), 1, dtype="f1")
        self.mask_fbo = ctx.framebuffer(color_attachments=[self.mask_tex])
        self.bg = ctx.program(vertex_shader=shaders.BACKGROUND_VS, fragment_shader=shaders.BACKGROUND_FS)
        self.bg_vao = ctx.vertex_array(self.bg, [])
        # The background gradient depends on the row only (every panel spans the frame's
        # height), so it is drawn once here and copied into each frame: llvmpipe blits between
        # same-format single-sampled buffers as a copy (~0.2 ms), not as a shaded pass (~2 ms).
        self.backdrop = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), 4)])
        self.backdrop.use()
        self.backdrop.viewport = (0, 0, w, h)
        self.bg["viewport"].value = (0.0, 0.0, float(w), float(h))
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.bg_vao.render(moderngl.TRIANGLES, vertices=3)
        self.mesh = ctx.program(vertex_shader=shaders.MESH_VS, fragment_shader=shaders.MESH_FS)
        self.shadow = ctx.program(vertex_shader=shaders.SHADOW_VS, fragment_shader=shaders.SHADOW_FS)
        self.ground = ctx.program(vertex_shader=shaders.GROUND_VS, fragment_shader=shaders.GROUND_FS)
        self.flat = ctx.program(vertex_shader=shaders.FLAT_VS, fragment_shader=shaders.FLAT_FS)
        self.composite = ctx.program(
            vertex_shader=shaders.BACKGROUND_VS, fragment_shader=shaders.COMPOSITE_FS
        )
        self.composite_vao = ctx.vertex_array(self.composite, [])
        self._owned = []
        self.out = np.empty((h, w, 4), np.uint8)  # RGBA: the GL-native read is 10x faster than RGB
        self._finish = _gil_free_finish(ctx)

    def _own(self, *objs):
        self._owned.extend(objs)
        return objs[0]

    def set_stage(
        self,
        bbox_min,
        bbox_max,
        ground_y: float,
        roots: list[np.ndarray],
        key_frames: np.ndarray,
        reach=EVERY_FRAME,
    ):
        """Static scene: ground plane, trajectories and key markers (frame indices ``key_frames``),
        drawn ``reach`` frames either side of the current one."""
        self.reach = min(float(reach), EVERY_FRAME)
        lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
        ext = hi - lo
        self.height = max(float(ext[1]), 1e-3)
        self.ground_y = float(ground_y)
        self.center = (lo + hi) / 2
        self.radius = float(max(ext[0], ext[2], self.height) * 2.2)
        # A "nice" grid spacing near a quarter of the character's height (0.5 m for a person).
        nice = np.array([1.0, 2.5, 5.0]) * 10.0 ** np.floor(np.log10(self.height / 4))
        self.cell = float(nice[np.argmin(np.abs(np.log(nice / (self.height / 4))))])
        self._set_ground()
        self._set_trajectories(roots, key_frames)

    def _set_ground(self):
        """The ground's quad, and the uniforms that do not change from frame to frame."""
        ctx = self.ctx
        c, r, y = self.center, self.radius, self.ground_y
        quad = np.array(
            [
                [c[0] - r, y, c[2] - r],
                [c[0] + r, y, c[2] - r],
                [c[0] + r, y, c[2] + r],
                [c[0] - r, y, c[2] - r],
                [c[0] + r, y, c[2] + r],
                [c[0] - r, y, c[2] + r],
            ],
            np.float32,
        )
        self.ground_vao = self._own(
            ctx.vertex_array(self.ground, [(self._own(ctx.buffer(quad.tobytes())), "3f", "in_pos")])
        )
        # what does not change from frame to frame is set once
        self.shadow["key_dir"].value = tuple(KEY_DIR)
        self.shadow["ground_y"].value = y
        self.ground["center"].value = (float(c[0]), float(c[2]))
        self.ground["radius"].value = r
        self.ground["cell"].value = self.cell
        self.ground["shadow_mask"].value = 0
        m = self.mesh
        m["key_dir"].value = tuple(KEY_DIR)
        m["fill_dir"].value = tuple(FILL_DIR)
        m["ground_y"].value = y
        m["ao_height"].value = self.height * 0.25

    def _set_trajectories(self, roots: list[np.ndarray], key_frames: np.ndarray):
        """The body joints' paths on the ground, the key markers along them and every key
        frame's ring, made once."""
        y = self.ground_y
        eps = self.height * 0.002
        w = self.height * 0.012
        tri = [_ribbon(rt, y + eps, w) for rt in roots if len(rt) > 1]
        marks = [
            _discs(rt[key_frames], y + 2 * eps, 0.0, self.height * 0.03, key_frames)
            for rt in roots
            if len(key_frames)
        ]
        # (vao, runs, colours) of the paths, then of the key marks: a frame draws the runs in view
        self.overlays = [
            (self._flat_vao(np.concatenate(t)), Runs(np.concatenate(t)), colors)
            for t, colors in zip((tri, marks), OVERLAY_COLORS, strict=True)
            if sum(map(len, t))
        ]
        self.roots = roots
        # every key frame's ring, made once into one buffer: frame -> (first vertex, count)
        self.rings, self.ring_vao = {}, None
        kf = [int(k) for k in np.asarray(key_frames).reshape(-1) if all(0 <= k < len(r) for r in roots)]
        if kf and roots:
            data = [self._ring(k) for k in kf]
            first = np.cumsum([0] + [len(d) for d in data])
            self.rings = {k: (int(first[n]), len(data[n]), data[n][:, :3]) for n, k in enumerate(kf)}
            self.ring_vao = self._flat_vao(np.concatenate(data))

    def _ring(self, frame: int) -> np.ndarray:
        """The KEY ring under the body joints at ``frame`` (flat triangles, t = 0)."""
        return _discs(
            np.array([r[frame] for r in self.roots]),
            self.ground_y + self.height * 0.006,
            self.height * 0.16,
            self.height * 0.19,
            np.zeros(len(self.roots)),
            seg=48,
        )

    def _flat_vao(self, data):
        if data is None or not len(data):
            return None
        buf = self._own(self.ctx.buffer(np.ascontiguousarray(data, np.float32).tobytes()))
        return self._own(self.ctx.vertex_array(self.flat, [(buf, "3f 1f", "in_pos", "in_t")]))

    def mesh_set(self, geoms: list[Geometry]) -> MeshSet:
        return MeshSet(self.ctx, self.mesh, self.shadow, geoms)

    def render(
        self,
        frame: int,
        cameras,
        sets: list[MeshSet],
        colors,
        is_key: bool,
        ghosts: MeshSet | None = None,
        out: np.ndarray | None = None,
    ):
        """One frame: panel k shows ``sets[k]`` through ``cameras[k]``; returns (h, w, 4) uint8:
        ``out`` if given, else a buffer reused from frame to frame."""
        w, h = self.size
        pw = w // self.panels
        self.ctx.copy_framebuffer(self.image, self.backdrop)  # the background (see ``__init__``)
        for k, (cam, ms, color) in enumerate(zip(cameras, sets, colors, strict=True)):
            self._render_panel(k, (k * pw, 0, pw, h), frame, cam, ms, color, is_key, ghosts)
        out = self.out if out is None else out
        self._finish()  # the frame's rasterisation, waited for without the GIL
        self.image.read_into(out, components=4, alignment=1)
        return out

    def _render_panel(self, k: int, vp_rect, frame: int, cam, ms: MeshSet, color, is_key: bool, ghosts):
        """Panel ``k``, in the viewport ``vp_rect``: ``ms`` through ``cam`` at ``frame``."""
        vp32 = cam.view_proj(frame)
        vp = vp32.T.copy()
        eye = cam.eye(frame)
        points = ms.upload(frame)
        self._draw_shadow_mask(vp_rect, vp, ms)
        self._draw_ground(vp_rect, vp)
        # 3. trajectory, markers, characters and ghosts: 4x MSAA over transparent black,
        # premultiplied, inside the rectangle they cover
        ring = self._key_ring(frame) if is_key else None
        in_view = [runs.visible(vp32) & runs.near(frame, self.reach) for _, runs, _ in self.overlays]
        covered = [
            runs.points(keep) for (_, runs, _), keep in zip(self.overlays, in_view, strict=True)
        ] + points
        if ring is not None:
            covered.append(ring[2])
        if ghosts is not None:
            covered.append(ghosts.all_points())
        rect = screen_rect(vp32, vp_rect, covered)
        if rect is None:
            return
        if k:  # the layer was sampled by the previous panel's composite: waited for without the GIL
            self._finish()
        mgl = self.mgl
        self.msaa.use()
        self.msaa.viewport = vp_rect
        self.msaa.scissor = rect
        self.msaa.clear(0.0, 0.0, 0.0, 0.0, depth=1.0, viewport=rect)
        self.ctx.blend_func = mgl.SRC_ALPHA, mgl.ONE_MINUS_SRC_ALPHA, mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
        self._draw_overlays(frame, vp, ring, in_view)
        self._draw_characters(vp, eye, ms, color, ghosts)
        self.msaa.scissor = None
        self._composite(rect)

    def _draw_shadow_mask(self, vp_rect, vp, ms: MeshSet):
        """1. The shadow mask: characters projected along the key light."""
        self.mask_fbo.use()
        self.mask_fbo.viewport = vp_rect
        self.mask_fbo.clear(0.0, viewport=vp_rect)
        self.ctx.disable(self.mgl.DEPTH_TEST | self.mgl.BLEND)
        self.shadow["vp"].write(vp)
        ms.draw(self.shadow, shadow=True)
        # llvmpipe waits for a texture's drawing before it is sampled, inside the draw call
        # and holding the GIL; waited for here instead, without it (as the two below)
        self._finish()

    def _draw_ground(self, vp_rect, vp):
        """2. The ground (with the mask) over the background, single-sampled into the image."""
        mgl, ctx = self.mgl, self.ctx
        self.image.use()
        self.image.viewport = vp_rect
        ctx.enable(mgl.BLEND)
        ctx.blend_func = mgl.SRC_ALPHA, mgl.ONE_MINUS_SRC_ALPHA
        self.mask_tex.use(0)
        self.ground["vp"].write(vp)
        self.ground_vao.render()

    def _key_ring(self, frame: int):
        """The KEY ring of a key frame: (first vertex, count, corners) in the rings' buffer,
        or (None, count, corners, triangles) for a key frame set_stage was not told of."""
        ring = self.rings.get(int(frame))
        if ring is None:  # a key frame set_stage was not told of
            data = self._ring(int(frame))
            ring = (None, len(data), data[:, :3], data)
        return ring

    def _draw_overlays(self, frame: int, vp, ring, in_view):
        """The trajectories (past and future), the key markers (the runs of them ``in_view``
        selects) and this key frame's ring."""
        self.flat["vp"].write(vp)
        self.flat["current"].value = float(frame)
        self.flat["reach"].value = self.reach
        for (vao, runs, (past, future)), keep in zip(self.overlays, in_view, strict=True):
            self.flat["color_past"].value = past
            self.flat["color_future"].value = future
            for first, count in runs.spans(keep):
                vao.render(first=first, vertices=count)
        if ring is not None:
            self.flat["reach"].value = EVERY_FRAME  # the ring's vertices carry no frame
            self.flat["color_past"].value = (1.0, 0.3, 0.1, 0.95)
            if ring[0] is None:
                self._flat_vao(ring[3]).render()
                self._release_last(2)
            else:
                self.ring_vao.render(first=ring[0], vertices=ring[1])

    def _draw_characters(self, vp, eye, ms: MeshSet, color, ghosts: MeshSet | None):
        """The characters, depth-tested, then the key ghosts blended over them."""
        mgl, ctx = self.mgl, self.ctx
        ctx.enable(mgl.DEPTH_TEST)
        ctx.disable(mgl.BLEND)
        m = self.mesh
        m["vp"].write(vp)
        m["eye"].value = tuple(float(v) for v in eye)
        m["base"].value = color
        m["alpha"].value = 1.0
        ms.draw(m)
        if ghosts is not None:
            ctx.enable(mgl.BLEND)
            self.msaa.depth_mask = False
            m["base"].value = GHOST
            m["alpha"].value = 0.15
            for i in range(ghosts.n_frames):
                ghosts.upload(i)
                ghosts.draw(m)
            self.msaa.depth_mask = True

    def _composite(self, rect):
        """4. The rectangle ``rect`` of the MSAA layer resolved and laid over the background."""
        mgl, ctx = self.mgl, self.ctx
        self._finish()
        ctx.disable(mgl.DEPTH_TEST)
        ctx.enable(mgl.BLEND)
        ctx.blend_func = mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
        self.image.use()
        self.image.scissor = rect
        self.layer.use(1)
        self.composite["layer"].value = 1
        self.composite["samples"].value = self.samples
        self.composite_vao.render(mgl.TRIANGLES, vertices=3)
        self.image.scissor = None

    def _release_last(self, n):
        for o in self._owned[-n:][::-1]:
            o.release()
        del self._owned[-n:]

    def release(self):
        for o in self._owned[::-1]:
            o.release()
        self._owned.clear()
        for o in (
            self.msaa,
            self.layer,
            self.image,
            self.backdrop,
            self.composite_vao,
            self.composite,
            self.mask_fbo,
            self.mask_tex,
            self.bg_vao,
            self.bg,
            self.mesh,
            self.shadow,
            self.ground,
            self.flat,
        ):
            o.release()
