"""OpenGL backend of the renderer: the numba ray caster (raycast.trace, shade.shade_pixel) and the fast motion blur
(renderer._blur_kernel) ported to GLSL 4.50 fragment shaders, run on a headless EGL context (moderngl; on machines
without a GPU, Mesa llvmpipe — its JIT runs the shader 8 pixels per SIMD instruction on all cores).

One fragment of a full-screen triangle = one pixel ray, same algorithm and branch order as the numba kernel, so images
agree closely (tests/world/test_gl_renderer.py states how closely); the differences are float32 rounding. Scene and
lighting setup (lighting vector, lamp zoning, texture atlas, locate, glare, sub-frame blur) is the base Renderer's;
the reference blur's sub-frame count still comes from its coarse (1/64 of the pixels) numba render.

float32 precision: routes span kilometres, where float32 resolves only ~0.1 mm… 0.5 mm. So the shader never sees an
absolute coordinate: every frame the CPU subtracts the camera position from the segment end points in float64 before
casting (rays start at the origin), arc lengths reach the shader as (tile cell index, metres past it) and modulo the
12 m dash period, and the blur pass gets the start/end poses relative to the rendered camera.

Speed on Mesa llvmpipe (2 cores, benchmarks/simulator_speed.py --backend both): the sharp render is ~1.4–1.6× slower
than the numba kernel — llvmpipe turns every uniform-block load with a per-pixel index (the segment table) into a
per-lane gather with a bounds check, and the walker is load-bound — while the smear pass is ~3–5× faster; end to end
(render + blur + glare + sensor) about equal at 640×480 and ~1.25× faster at 320×240. Measured choices: segment table
and scene parameters in uniform blocks (storage-buffer loads were ~4× dearer: 2.3× on the whole render), hardware
bilinear taps in the smear, segment axes derived from the forward axis.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

from expoctl.errors import ConfigError
from expoctl.world import raycast as rc
from expoctl.world import route as rt
from expoctl.world import daylight, shade
from expoctl.world.render_config import RenderConfig
from expoctl.world.renderer import Renderer

_SHADERS = Path(__file__).with_name("shaders")

# Direction-component threshold below which a ray counts as parallel to a plane. The numba value is kept: 1e-12 is a
# normal float32, and with camera-relative coordinates (≲ 1e3 m) a quotient by anything above it stays ≲ 1e15, far
# below INF = 1e30 (itself < float32 max 3.4e38), so every comparison against INF behaves as in float64.
EPS_DIR = 1.0e-12
# Slack of the cheap reach test before a block's/prop's exact test (numba: 1e-6 m for float64 rounding ~1e-13 m).
# In float32 the piece's end points (local coordinates ≲ 1e3 m) are rounded at ~6e-5 m per operation, a few
# operations deep; 1 mm covers that with margin and is still far below any block or prop size, so the test rejects
# as much as before and never rejects a hit of the exact test.
CULL_MARGIN_M = 1.0e-3

# extra per-segment columns appended to the route table for the shader (all computed in float64 on the CPU):
# arc-length splits (per city), and per frame the camera's local coordinates O0 (3) and the mitre-plane offsets
# NE·P1, NS·P0 relative to the camera
_C_SCELL, _C_SREM, _C_FCELL, _C_FREM, _C_S12, _C_TX0, _C_O0, _C_NE_D, _C_NS_D = (
    rt.NCOL, rt.NCOL + 1, rt.NCOL + 2, rt.NCOL + 3, rt.NCOL + 4, rt.NCOL + 5, rt.NCOL + 6, rt.NCOL + 9, rt.NCOL + 10)
SEG_STRIDE = (rt.NCOL + 11 + 3) // 4 * 4  # whole vec4s per segment (uniform-block layout, shaders/trace.glsl)

_CTX = None  # one GL context per process, created on first use
_CTX_PID = None  # a forked child inherits _CTX but not a usable context: it makes its own (forking while llvmpipe's
# threads exist can still deadlock inside Mesa; the project's pools spawn their workers)
_PROGRAMS: dict = {}
_ATLAS_BUFFERS: dict = {}  # id(texels) → (texels array kept alive, buffers): cities sharing an atlas share it on the GPU


def gl_context():
    """The process's headless EGL OpenGL 4.5 context (created on first call)."""
    global _CTX, _CTX_PID
    if _CTX is not None and _CTX_PID != os.getpid():
        _CTX = None
        _PROGRAMS.clear()
        _ATLAS_BUFFERS.clear()
    if _CTX is None:
        try:
            import moderngl
            _CTX = moderngl.create_standalone_context(backend="egl", require=450)
        except Exception as exc:  # missing moderngl, libEGL, or a driver without GL 4.5
            raise ConfigError("world.render.backend",
                              f"'egl' needs an OpenGL 4.5 context through headless EGL (moderngl + Mesa libEGL), "
                              f"but creating one failed: {exc}; use backend: numba") from exc
        _CTX_PID = os.getpid()
    return _CTX


def _header() -> str:
    """GLSL constants generated from route.py / raycast.py / shade.py, so the shader's column indices cannot drift."""
    ints = {f"C_{k}": getattr(rt, k) for k in ("P0", "F", "R", "U", "NS", "NE", "P1", "KIND", "HW", "WALL_H",
                                                "CROWN_H", "ARC_C", "ARC_R", "HILL_H", "TUN_ID", "TUN_LEN", "L_OFF",
                                                "L_H", "L_MAT", "R_OFF", "R_H", "R_MAT", "VMAX", "BOX0",
                                                "BOX_STRIDE", "N_BOXES")}
    ints["ARC_EDGES"] = daylight.ARC_EDGES
    ints.update(C_SCELL=_C_SCELL, C_SREM=_C_SREM, C_FCELL=_C_FCELL, C_FREM=_C_FREM, C_S12=_C_S12, C_TX0=_C_TX0,
                C_O0=_C_O0, C_NE_D=_C_NE_D, C_NS_D=_C_NS_D,
                SEG_STRIDE=SEG_STRIDE, MAT_SKY=shade.MAT_SKY, MAT_LAMP=shade.MAT_LAMP)
    for name in dir(rc):
        if name.startswith(("LP_", "MAT_")) or name in ("SKY", "GROUND", "SIDE", "ROOF", "TWALL", "TCEIL", "FACE",
                                                         "HILLTOP", "FAR", "PROP"):
            ints[name] = getattr(rc, name)
    lines = ["#version 450"]
    lines += [f"const int {k} = {int(v)};" for k, v in sorted(ints.items())]
    floats = {"INF": rc.INF, "EPS_DIR": EPS_DIR, "CULL_MARGIN_M": CULL_MARGIN_M, "PI": math.pi,
              "KIND_TUNNEL": rt.KIND_TUNNEL, "NO_BLOCK_OFFSET": rt.NO_BLOCK_OFFSET}
    lines += [f"const float {k} = {float(v)!r};" for k, v in floats.items()]
    return "\n".join(lines) + "\n"


def _vec4s(n: int) -> int:
    return max(1, (int(n) + 3) // 4)


def _programs(ctx, sizes: dict):
    """(render program, blur program) for these array sizes (uniform-block arrays are sized at compile time)."""
    key = tuple(sorted(sizes.items()))
    if key not in _PROGRAMS:
        vert = (_SHADERS / "fullscreen_vert.glsl").read_text()
        defs = "".join(f"#define {k} {int(v)}\n" for k, v in sizes.items() if k != "SEG_IN_UBO")
        if sizes["SEG_IN_UBO"]:
            defs += "#define SEG_IN_UBO\n"
        render_src = (_header() + defs + (_SHADERS / "trace.glsl").read_text()
                      + (_SHADERS / "shade.glsl").read_text())
        _PROGRAMS[key] = (ctx.program(vertex_shader=vert, fragment_shader=render_src),
                          ctx.program(vertex_shader=vert, fragment_shader=(_SHADERS / "blur.glsl").read_text()))
    return _PROGRAMS[key]


def _seg_fits_uniform_block(ctx, nbytes: int) -> bool:
    """Whether the segment table fits a uniform block (64 KiB on llvmpipe: ~200 segments); else a storage buffer."""
    return nbytes <= ctx.info["GL_MAX_UNIFORM_BLOCK_SIZE"]


def _set(prog, name, value):
    """Set a uniform if the compiler kept it (unused uniforms are optimised away)."""
    if name in prog:
        if isinstance(value, (bytes, bytearray)):
            prog[name].write(value)
        else:
            prog[name].value = value


def _pad4(a, dtype) -> bytes:
    """Values as a whole number of vec4/ivec4 (std140 array elements)."""
    a = np.asarray(a).ravel().astype(dtype)
    return np.concatenate([a, np.zeros(_vec4s(a.size) * 4 - a.size, dtype)]).tobytes()


def _mat3(m) -> bytes:
    return np.asarray(m, np.float64).T.astype(np.float32).tobytes()  # GLSL matrices are column-major


def shader_segments(seg: np.ndarray, texel_m: float, tile_px: int) -> np.ndarray:
    """The route table plus the float64-derived columns the shader uses instead of absolute arc lengths."""
    tile_m = tile_px * texel_m
    out = np.zeros((seg.shape[0], SEG_STRIDE))
    out[:, : rt.NCOL] = seg
    s0 = seg[:, rt.S0]
    out[:, _C_SCELL] = np.floor(s0 / tile_m)
    out[:, _C_SREM] = s0 - out[:, _C_SCELL] * tile_m
    f = 37.0 * s0  # the along-face texture coordinate of portal faces and prop ends is v + 37·S0 (shade_pixel)
    out[:, _C_FCELL] = np.floor(f / tile_m)
    out[:, _C_FREM] = f - out[:, _C_FCELL] * tile_m
    out[:, _C_S12] = np.mod(s0, 12.0)  # lane-divider dash period (shade._road_marking)
    tun = seg[:, rt.KIND] == rt.KIND_TUNNEL
    out[:, _C_TX0] = np.where(tun, s0 - seg[:, rt.TUN_S0], 0.0)
    return out


class GLRenderer(Renderer):
    """Renderer whose render_full and fast motion blur run as GLSL shaders (see module docstring); same outputs."""

    def __init__(self, city, render: RenderConfig | None = None, conditions=None):
        if render is not None and render.portal_daylight != "exact":  # the shader integrates per pixel
            raise ConfigError("world.render.portal_daylight",
                              f"{render.portal_daylight!r} needs backend numba; the egl shader has only 'exact'")
        super().__init__(city, render, conditions)
        if len(set(self.sizes[:, 0].tolist())) != 1:
            raise ValueError("all material tiles must have the same size (one tile length per route cell)")
        self._seg64 = shader_segments(self.seg, float(self._base_lp[rc.LP_TEXEL_M]), int(self.sizes[0, 0]))
        self._gl = None  # GL objects, created on first render (not pickled)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_gl"] = None
        return state

    # ------------------------------------------------------------------ GL resources
    def _gl_state(self) -> dict:
        if self._gl is not None and self._gl["pid"] == os.getpid():
            return self._gl
        ctx = gl_context()
        n_mat = self.offs.shape[0]
        seg_bytes = self._seg64.size * 4
        sizes = {"N_MAT": n_mat, "LP_VEC4": _vec4s(rc.LP_N), "LAMP_VEC4": _vec4s(self.lamp_mult.size),
                 "PORTAL_VEC4": _vec4s(4 * len(self._lamp_count)), "TUN_VEC4": _vec4s(len(self._lamp_count)), "LEVEL_VEC4": _vec4s(2 * self.offs.size),
                 "MAT_VEC4": _vec4s(2 * n_mat), "SEG_IN_UBO": int(_seg_fits_uniform_block(ctx, seg_bytes)),
                 "SEG_VEC4_TOTAL": self._seg64.size // 4}
        prog, blur = _programs(ctx, sizes)
        key = id(self.texels)
        if key not in _ATLAS_BUFFERS or _ATLAS_BUFFERS[key][0] is not self.texels:
            if len(_ATLAS_BUFFERS) >= 3:
                for _, bufs in _ATLAS_BUFFERS.values():
                    for b in bufs:
                        b.release()
                _ATLAS_BUFFERS.clear()
            # RGB bytes → one RGBA word per texel, built as bytes (no uint32 temporaries: the atlas is ~60 MB);
            # unpackUnorm4x8 reads r from the low byte, which is byte 0 on a little-endian host
            assert sys.byteorder == "little"
            rgba = np.zeros((self.texels.size // 3, 4), np.uint8)
            rgba[:, :3] = self.texels.reshape(-1, 3)
            packed = rgba.ravel()
            if np.any(self.offs % 3):
                raise ValueError("texture atlas levels must start on a texel boundary")
            _ATLAS_BUFFERS[key] = (self.texels, (ctx.buffer(packed),))
        texel_buf = _ATLAS_BUFFERS[key][1][0]
        w, h = self.width, self.height
        sharp = ctx.texture((w, h), 4, dtype="f4")
        codes = ctx.texture((w, h), 2, dtype="u1")
        smeared = ctx.texture((w, h), 4, dtype="f4")
        upload = ctx.texture((w, h), 4, dtype="f4")
        for t in (codes, smeared):
            t.filter = (ctx.NEAREST, ctx.NEAREST)
        for t in (sharp, upload):  # the blur pass samples them bilinearly
            t.filter = (ctx.LINEAR, ctx.LINEAR)
            t.repeat_x = t.repeat_y = False
        levels = np.concatenate([(self.offs // 3).ravel(), self.sizes.ravel()])
        mat_props = np.concatenate([self.albedo, self.scales])
        # the Params block's constant arrays (offsets in 16-byte vec4 units); lp, lamp_mult and portal_lum change
        # per conditions
        self._params_static = (_pad4(self._lamp_count, np.int32), _pad4(levels, np.int32), _pad4(mat_props, np.float32))
        params_bytes = 16 * (sizes["LP_VEC4"] + sizes["LAMP_VEC4"] + sizes["PORTAL_VEC4"] + sizes["TUN_VEC4"]
                             + sizes["LEVEL_VEC4"] + sizes["MAT_VEC4"])
        if params_bytes > ctx.info["GL_MAX_UNIFORM_BLOCK_SIZE"]:
            raise ValueError(f"too many tunnel lamps for the GL backend's uniform block ({params_bytes} bytes)")
        self._gl = {
            "pid": os.getpid(), "ctx": ctx, "prog": prog, "blur": blur, "vao": ctx.vertex_array(prog, []),
            "vao_blur": ctx.vertex_array(blur, []), "texels": texel_buf, "seg_in_ubo": bool(sizes["SEG_IN_UBO"]),
            "seg": ctx.buffer(reserve=seg_bytes), "params": ctx.buffer(reserve=params_bytes),
            "sharp": sharp, "codes": codes, "fbo": ctx.framebuffer([sharp, codes]),
            "smeared": smeared, "fbo_blur": ctx.framebuffer([smeared]), "upload": upload,
            "hdri": None, "hdri_src": None, "sharp_src": None,
        }
        return self._gl

    def _hdri_texture(self, gl):
        if gl["hdri_src"] is not self.hdri:  # new conditions: upload their sky map once
            if gl["hdri"] is not None:
                gl["hdri"].release()
            img = np.ascontiguousarray(self.hdri, np.float32)
            tex = gl["ctx"].texture((img.shape[1], img.shape[0]), 3, img.tobytes(), dtype="f4")
            tex.filter = (gl["ctx"].NEAREST, gl["ctx"].NEAREST)
            gl["hdri"], gl["hdri_src"] = tex, self.hdri
        return gl["hdri"]

    # ------------------------------------------------------------------ rendering
    def render_full(self, pose: np.ndarray, glare: bool = True) -> dict:
        """As Renderer.render_full, rendered by the GLSL port of the ray caster."""
        pose = np.asarray(pose, dtype=np.float64)
        i0, inside = self.locate(pose[:3, 3])
        gl = self._gl_state()
        seg = self._seg64.copy()
        cam = pose[:3, 3]
        seg[:, rt.P0:rt.P0 + 3] -= cam  # camera-relative, in float64, before the cast (see module docstring)
        seg[:, rt.P1:rt.P1 + 3] -= cam
        p0, p1 = seg[:, rt.P0:rt.P0 + 3], seg[:, rt.P1:rt.P1 + 3]
        for k, col in enumerate((rt.F, rt.R, rt.U)):
            seg[:, _C_O0 + k] = -np.einsum("ij,ij->i", seg[:, col:col + 3], p0)
        seg[:, _C_NE_D] = np.einsum("ij,ij->i", seg[:, rt.NE:rt.NE + 3], p1)
        seg[:, _C_NS_D] = np.einsum("ij,ij->i", seg[:, rt.NS:rt.NS + 3], p0)
        gl["seg"].write(seg.astype(np.float32).tobytes())
        gl["params"].write(b"".join([_pad4(self.lp, np.float32), _pad4(self.lamp_mult.ravel(), np.float32),
                                     _pad4(self.portal_lum.ravel(), np.float32), *self._params_static]))
        if gl["seg_in_ubo"]:
            gl["seg"].bind_to_uniform_block(0)
        else:
            gl["seg"].bind_to_storage_buffer(0)
        gl["params"].bind_to_uniform_block(1)
        gl["texels"].bind_to_storage_buffer(4)
        prog = gl["prog"]
        K = self.K
        _set(prog, "n_seg", int(seg.shape[0]))
        _set(prog, "lamp_stride", int(self.lamp_mult.shape[1]))
        _set(prog, "n_lev", int(self.offs.shape[1]))
        _set(prog, "rot", _mat3(pose[:3, :3]))
        _set(prog, "intr", (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        _set(prog, "start_seg", int(i0))
        _set(prog, "start_inside", bool(inside))
        _set(prog, "cull", bool(self.cull))
        _set(prog, "hdri", 0)
        self._hdri_texture(gl).use(0)
        gl["fbo"].use()
        gl["vao"].render(mode=gl["ctx"].TRIANGLES, vertices=3)
        h, w = self.height, self.width
        ld = np.empty((h, w, 4), np.float32)
        cm = np.empty((h, w, 2), np.uint8)
        gl["fbo"].read_into(ld, components=4, attachment=0, dtype="f4")
        gl["fbo"].read_into(cm, components=2, attachment=1, dtype="u1")
        lum = np.ascontiguousarray(ld[..., :3])
        gl["sharp_src"] = lum  # the sharp texture holds this image (+ depth): the blur pass needs no upload
        out = {"luminance": lum, "depth": np.ascontiguousarray(ld[..., 3]),
               "code": np.ascontiguousarray(cm[..., 0]), "material": np.ascontiguousarray(cm[..., 1])}
        if glare:
            out["luminance"] = self.apply_glare(lum)
        return out

    def _smear(self, sharp: dict, pose_a: np.ndarray, pose_b: np.ndarray) -> tuple[np.ndarray, float]:
        """As Renderer._smear (the numba _blur_kernel), as a second GL pass over the sharp luminance + depth."""
        gl = self._gl_state()
        if gl["sharp_src"] is sharp["luminance"]:
            src = gl["sharp"]
        else:  # a cached render that is no longer on the GPU (e.g. the other camera rendered in between)
            src = gl["upload"]
            ld = np.concatenate([sharp["luminance"], sharp["depth"][..., None]], axis=2).astype(np.float32)
            src.write(ld.tobytes())
        ref = np.asarray(sharp["pose"], np.float64)
        blur = gl["blur"]
        for name, pose in (("a", pose_a), ("b", pose_b)):
            pose = np.asarray(pose, np.float64)
            # q = R_pᵀ (R_ref p + t_ref − t_p): composed in float64, so no km-scale coordinate reaches the shader
            m = pose[:3, :3].T @ ref[:3, :3]
            t = pose[:3, :3].T @ (ref[:3, 3] - pose[:3, 3])
            _set(blur, f"m_{name}", _mat3(m))
            _set(blur, f"t_{name}", tuple(float(v) for v in t))
        K = self.K
        _set(blur, "intr", (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        _set(blur, "sharp", 0)
        src.use(0)
        gl["fbo_blur"].use()
        gl["vao_blur"].render(mode=gl["ctx"].TRIANGLES, vertices=3)
        res = np.empty((self.height, self.width, 4), np.float32)
        gl["fbo_blur"].read_into(res, components=4, attachment=0, dtype="f4")
        return np.ascontiguousarray(res[..., :3]), float(res[..., 3].max())
