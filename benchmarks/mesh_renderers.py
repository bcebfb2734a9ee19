"""The mesh condition's renderer choice: oscar's NumPy z-buffer against OpenGL (moderngl, headless EGL).

    pip install moderngl            # not a dependency of oscar; Mesa's EGL (llvmpipe) from the system
    python benchmarks/mesh_renderers.py [--cells 0 0.008] [--frames 40] [--json benchmarks/results/mesh_renderers.json]

Both draw the same triangles: franka's visual meshes (``--cells``: vertex-clustering
cell in metres, 0 for the full meshes), moved by FK and projected by oscar
(so both see identical pixel positions; the GL path adds no projection of its
own), flat-shaded with the same colours, at 512x288, llvmpipe on one thread
(``LP_NUM_THREADS=1``) as NumPy on one core. Per cell it prints frames/s of
each and the IoU of their silhouettes, and writes JSON. Without moderngl it
prints why and times NumPy alone.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")
os.environ.setdefault("LP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from oscar_core import get_embodiment, load_camera, load_trajectory  # noqa: E402
from oscar_core.render.mesh import MESH, MeshStyle, render_mesh_video, vertices_cv  # noqa: E402
from oscar_core.render.mesh_raster import shade_faces  # noqa: E402

SIZE = (512, 288)
NEAR, FAR = 0.05, 10.0  # metres: the GL depth range (linear depth)


class GLRenderer:
    """moderngl on a headless EGL context: per frame, upload flat-coloured triangles in pixels, draw, read back."""

    def __init__(self, faces: int):
        import moderngl

        self.mgl = moderngl
        self.ctx = moderngl.create_standalone_context(backend="egl")
        self.prog = self.ctx.program(
            vertex_shader="""#version 330
in vec3 p; in vec3 c; out vec3 vc; uniform vec2 size;
void main() { vc = c; gl_Position = vec4(p.x / size.x * 2.0 - 1.0, 1.0 - p.y / size.y * 2.0, p.z, 1.0); }""",
            fragment_shader="""#version 330
in vec3 vc; out vec4 o; void main() { o = vec4(vc, 1.0); }""",
        )
        self.prog["size"].value = SIZE
        self.fbo = self.ctx.simple_framebuffer(SIZE, components=3)
        self.fbo.use()
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.vbo = self.ctx.buffer(reserve=faces * 3 * 6 * 4)
        self.vao = self.ctx.vertex_array(self.prog, [(self.vbo, "3f 3f", "p", "c")])

    @property
    def name(self) -> str:
        return self.ctx.info["GL_RENDERER"]

    def render(self, job, T: int) -> np.ndarray:
        W, H = SIZE
        _, Pc, uv, _ = vertices_cv(job, 0, T)
        out = np.empty((T, H, W, 3), np.uint8)
        faces = job.mesh.faces
        for i in range(T):
            rgb = shade_faces(Pc[i], faces, job.mesh.face_rgb).astype(np.float32) / 255
            ndc_z = (Pc[i, :, 2] - NEAR) / (FAR - NEAR) * 2 - 1
            # GL pixel centres are at +0.5, oscar's at integers
            pos = np.concatenate([uv[i] + 0.5, ndc_z[:, None]], 1).astype(np.float32)[faces]
            self.vbo.write(np.ascontiguousarray(np.concatenate([pos, np.repeat(rgb[:, None], 3, 1)], 2)).tobytes())
            self.fbo.clear(0, 0, 0, depth=1.0)
            self.vao.render(self.mgl.TRIANGLES)
            out[i] = np.frombuffer(self.fbo.read(components=3), np.uint8).reshape(H, W, 3)[::-1]
        return out


def best_time(fn, repeats: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", type=float, nargs="*", default=[0.0, 0.008])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "mesh_renderers.json"))
    args = ap.parse_args(argv)
    emb = get_embodiment("franka")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, args.frames)
    cam = load_camera(emb.example_camera).resized(*SIZE)
    rows, gl_note = [], None
    for cell in args.cells:
        style = MeshStyle(simplify=cell or None)
        job = MESH.prepare(
            emb, traj, cam, None, style=style, resize_mode="crop", device="cpu", camera_source="<camera>"
        )
        T = len(traj)
        render_mesh_video(emb, traj.time_slice(0, 1), cam, style=style)
        t_np, ours = best_time(lambda: render_mesh_video(emb, traj, cam, style=style), args.repeats)
        row = {
            "embodiment": "franka",
            "size": f"{SIZE[0]}x{SIZE[1]}",
            "simplify_m": cell or None,
            "triangles": len(job.mesh.faces),
            "numpy_fps": T / t_np,
            "gl_fps": None,
            "gl_renderer": None,
            "silhouette_iou": None,
        }
        try:
            gl = GLRenderer(len(job.mesh.faces))
        except Exception as exc:  # noqa: BLE001 - no moderngl, or no EGL: say so and go on
            gl_note = f"OpenGL path skipped: {type(exc).__name__}: {exc}"
        else:
            gl.render(job, 1)
            t_gl, theirs = best_time(lambda: gl.render(job, T), args.repeats)
            a, b = ours.any(-1), theirs.any(-1)
            row.update(gl_fps=T / t_gl, gl_renderer=gl.name, silhouette_iou=float((a & b).sum() / (a | b).sum()))
        rows.append(row)
    print(
        f"franka mesh condition at {SIZE[0]}x{SIZE[1]}, {args.frames} frames, one thread each (best of {args.repeats})"
    )
    print(f"{'simplify_m':>10}  {'triangles':>9}  {'numpy_fps':>9}  {'gl_fps':>7}  {'silhouette_iou':>14}")
    for r in rows:
        gl_fps = "-" if r["gl_fps"] is None else f"{r['gl_fps']:.0f}"
        iou = "-" if r["silhouette_iou"] is None else f"{r['silhouette_iou']:.4f}"
        print(f"{str(r['simplify_m']):>10}  {r['triangles']:>9}  {r['numpy_fps']:>9.0f}  {gl_fps:>7}  {iou:>14}")
    if gl_note:
        print(gl_note)
    elif rows:
        print(f"OpenGL renderer: {rows[0]['gl_renderer']}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "note": gl_note, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
