"""Ray-traced camera images of the simulated cell (Embree via trimesh), with a powder mask.

Why not pybullet's TinyRenderer: 29–47 fps at small sizes, no per-pixel material control
and hangs with a camera on a joint (notes/planning.md §6). Here one primary ray per pixel
is cast against the whole cell (floor, walls, bin, its board, mobile base, arm capsules,
camera body); each hit is shaded by material:

* bin **external** faces: brushed stainless — grey albedo with fine streaks along the grain,
  broad specular lobe;
* bin **internal** faces: polished stainless — dark base reflecting a synthetic cabin
  environment (bright ceiling, light panels), sharp saturated highlights;
* the **ChArUco board**: the image of :func:`cellctl.geometry.boards.board_image`, matte;
* **powder** (dirty scenarios): matte near-white, opacity from
  :class:`cellctl.sim.ground_truth.PowderField`; ``powder_mask`` marks pixels where it shows.

No shadows or inter-reflections. Camera model: pinhole (:class:`cellctl.geometry.camera.CameraModel`
or a capture's ``Intrinsics``; distortion ignored),
exposure, gamma 2.2, Gaussian sensor noise (seeded).

For the classifier's dataset synthesis (in-process)::

    from cellctl.geometry.camera import D435_COLOR
    from cellctl.sim.render import SimRenderer, RenderParams
    r = SimRenderer(catalog)                          # catalog = load_catalog("config/bins.yaml")
    out = r.render_bin_view("case_study", T_bin_cam, D435_COLOR.scaled(0.25),
                            dirty=True, powder_amount=0.6, seed=3,
                            params=RenderParams(exposure=1.1, light_scale=0.9, powder_rgb=(0.95, 0.94, 0.9)))
    out.rgb          # (H, W, 3) uint8
    out.powder_mask  # (H, W) bool, powder visible at that pixel
    out.surface      # (H, W) int8: -1 not the bin, 0 external, 1 internal

``T_bin_cam`` is the camera optical frame (+Z forward, +Y down) in the bin frame. 320×180
renders take ~40 ms, 1280×720 ~0.4 s (``cellctl bench sim``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.errors import ConfigError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.camera import CameraModel
from cellctl.geometry.catalog import Catalog
from cellctl.geometry.transforms import invert
from cellctl.messages import Intrinsics
from cellctl.sim.ground_truth import PowderField, SprayPass, value_noise3
from cellctl.sim.scene import CABIN_HALF, CABIN_HEIGHT, Scenario
from cellctl.surface import EXTERNAL, INTERNAL

__all__ = ["CameraLike", "RenderParams", "RenderResult", "SimRenderer"]

CameraLike = CameraModel | Intrinsics
"""What the renderer projects with: the camera model, or the intrinsics a capture reports."""

TILE_PIXELS = 1 << 15
"""Pixels cast and shaded at once. A whole frame at once held ~130 MB of temporaries at
640x360 and ~440 MB at 1280x720, and the camera worker's allocator kept each high-water
mark (the soak's RSS steps); tiles bound that to ~28 MB at 1280x720, same image bit for bit."""

# material ids
M_FLOOR, M_WALL, M_BIN_EXT, M_BIN_INT, M_BOARD, M_BASE, M_ROBOT, M_CAMERA = range(8)


@dataclass(frozen=True)
class RenderParams:
    """Appearance knobs (randomise them for dataset synthesis).

    Attributes:
        exposure: linear gain before gamma.
        light_scale: scales both cabin lights.
        light_offset: moves the lights (m, world frame) — changes where highlights fall.
        powder_rgb: linear powder albedo.
        noise_sigma: sensor noise (8-bit grey levels).
        ambient: ambient light level.
    """

    exposure: float = 1.0
    light_scale: float = 1.0
    light_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    powder_rgb: tuple[float, float, float] = (0.93, 0.93, 0.90)
    noise_sigma: float = 2.0
    ambient: float = 0.16


@dataclass
class RenderResult:
    """One rendered frame."""

    rgb: NDArray[np.uint8]
    powder_mask: NDArray[np.bool_]
    surface: NDArray[np.int8]
    depth: NDArray[np.float32] = field(repr=False)


def _box(centre: NDArray[np.float64], size: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    import trimesh

    b = trimesh.creation.box(extents=size)
    return np.asarray(b.vertices) + centre, np.asarray(b.faces)


def _quad(c0: ArrayLike, c1: ArrayLike, c2: ArrayLike, c3: ArrayLike) -> tuple[NDArray, NDArray]:
    return np.array([c0, c1, c2, c3], dtype=np.float64), np.array([[0, 1, 2], [0, 2, 3]])


class _Noise1D:
    """Streak tables for brushed steel (seeded, fixed)."""

    def __init__(self) -> None:
        rng = np.random.default_rng(12345)
        self.fine = rng.normal(size=8192)
        k = np.ones(9) / 9
        self.fine = np.convolve(np.concatenate([self.fine, self.fine[:8]]), k, mode="valid")[:8192]
        self.fine /= np.abs(self.fine).max()

    def __call__(self, s: NDArray[np.float64], scale: float) -> NDArray[np.float64]:
        x = s / scale
        i = np.floor(x).astype(np.int64)
        f = x - i
        a, b = self.fine[i % 8192], self.fine[(i + 1) % 8192]
        return a + f * (b - a)


_STREAKS = _Noise1D()


class SimRenderer:
    """Renders the simulated cell. Holds per-bin caches (board textures, powder fields).

    Args:
        catalog: the bin catalog (meshes, boards).
    """

    def __init__(self, catalog: Catalog) -> None:
        self.catalog = catalog
        self._boards: dict[str, NDArray[np.float64]] = {}
        self._powder: dict[tuple, PowderField] = {}
        self._rays: dict[tuple, NDArray[np.float32]] = {}

    # --- scene assembly -------------------------------------------------------------------

    def _board_texture(self, name: str) -> NDArray[np.float64]:
        if name not in self._boards:
            from cellctl.geometry.boards import board_image

            self._boards[name] = board_image(self.catalog.get(name).board, 60).astype(np.float64) / 255.0
        return self._boards[name]

    def _ray_dirs(self, K: CameraLike) -> NDArray[np.float32]:
        """Unit ray directions (H·W, 3) in the camera frame, cached per intrinsics."""
        key = (K.width, K.height, K.fx, K.fy, K.cx, K.cy)
        if key not in self._rays:
            if len(self._rays) > 8:
                self._rays.clear()
            # OpenCV convention (Intrinsics, cv2): integer pixel coordinates are pixel centres;
            # "+ 0.5" here shifts the image by half a pixel and biases every board pose (vision).
            u, v = np.meshgrid(np.arange(K.width, dtype=np.float64), np.arange(K.height, dtype=np.float64))
            d = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], -1).reshape(-1, 3)
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            self._rays[key] = d.astype(np.float32)
        return self._rays[key]

    def powder(self, name: str, dirty: bool, amount: float, seed: int) -> PowderField:
        """The powder field of a scenario (cached)."""
        key = (name, bool(dirty), round(float(amount), 6), int(seed))
        if key not in self._powder:
            mesh = self.catalog.load_mesh(name)
            self._powder[key] = PowderField.sample(mesh, amount if dirty else 0.0, seed)
        return self._powder[key]

    def _scene(
        self,
        name: str,
        T_world_bin: NDArray[np.float64],
        T_world_base: NDArray[np.float64] | None,
        joints: NDArray[np.float64] | None,
        cell: bool,
    ) -> tuple:
        import trimesh

        parts_v, parts_f, parts_m = [], [], []
        n = 0

        def add(V: NDArray, F: NDArray, mat: NDArray | int) -> None:
            nonlocal n
            parts_v.append(V)
            parts_f.append(F + n)
            parts_m.append(np.broadcast_to(np.asarray(mat, dtype=np.int8), (len(F),)))
            n += len(V)

        mesh = self.catalog.load_mesh(name)
        bt = self.catalog.get(name)
        Vb = mesh.vertices @ T_world_bin[:3, :3].T + T_world_bin[:3, 3]
        add(Vb, mesh.faces, np.where(mesh.surface == INTERNAL, M_BIN_INT, M_BIN_EXT).astype(np.int8))
        w, h = bt.board.size_m
        Tb = T_world_bin @ bt.T_bin_board()
        corners = (Tb @ np.array([[0, 0, 0, 1], [w, 0, 0, 1], [w, h, 0, 1], [0, h, 0, 1]], dtype=float).T).T[:, :3]
        add(*_quad(*corners), M_BOARD)
        if cell:
            hx, hy = CABIN_HALF
            add(*_quad([-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]), M_FLOOR)
            H = CABIN_HEIGHT
            for a, b in (
                ((-hx, -hy), (hx, -hy)),
                ((hx, -hy), (hx, hy)),
                ((hx, hy), (-hx, hy)),
                ((-hx, hy), (-hx, -hy)),
            ):
                add(*_quad([*a, 0], [*b, 0], [*b, H], [*a, H]), M_WALL)
        if T_world_base is not None:
            c, s = rm.MOBILE_BASE_BOX
            V, F = _box(c, s)
            add(V @ T_world_base[:3, :3].T + T_world_base[:3, 3], F, M_BASE)
            if joints is not None:
                frames = T_world_base @ rm.link_frames(joints)[0]
                for cap in rm.CAPSULES:
                    p0, p1 = np.array(cap.p0), np.array(cap.p1)
                    L = float(np.linalg.norm(p1 - p0))
                    cm = trimesh.creation.capsule(height=L, radius=cap.radius, count=[10, 6])
                    ax = (p1 - p0) / max(L, 1e-9)
                    zc = np.array([0.0, 0.0, 1.0])
                    v = np.cross(zc, ax)
                    if np.linalg.norm(v) < 1e-9:
                        R = np.eye(3) if ax[2] > 0 else np.diag([1.0, -1.0, -1.0])
                    else:
                        from cellctl.geometry.transforms import rotation_about

                        R = rotation_about(v, float(np.arccos(np.clip(ax @ zc, -1, 1))))
                    V = np.asarray(cm.vertices) @ R.T + (p0 + p1) / 2
                    Tl = frames[cap.link]
                    mat = M_CAMERA if cap.name == "camera" else M_ROBOT
                    add(V @ Tl[:3, :3].T + Tl[:3, 3], np.asarray(cm.faces), mat)
        V = np.vstack(parts_v)
        F = np.vstack(parts_f)
        M = np.concatenate(parts_m)
        return V, F, M, Tb

    # --- rendering --------------------------------------------------------------------------

    def render(
        self,
        scenario: Scenario,
        T_world_cam: ArrayLike,
        intrinsics: CameraLike,
        joints: ArrayLike | None = None,
        params: RenderParams | None = None,
        seed: int = 0,
        cell: bool = True,
        washes: Sequence[SprayPass] = (),
    ) -> RenderResult:
        """Render the scenario's world from a camera pose.

        Args:
            scenario: bin type/pose, dirt, parked base pose.
            T_world_cam: camera optical frame in the world frame (4, 4).
            intrinsics: pinhole camera.
            joints: arm joints (rad) to draw the arm; None draws no arm.
            params: appearance.
            seed: sensor-noise seed.
            cell: draw floor and cabin walls.
            washes: spray passes run over the bin so far (bin frame): the powder they removed is gone.

        Raises:
            ConfigError: unknown bin type.
        """
        bt = self.catalog.get(scenario.bin_type)
        T_world_bin = scenario.T_world_bin(bt)
        T_world_base = scenario.base() if scenario.T_world_base is not None else None
        q = None if joints is None else np.asarray(joints, dtype=np.float64)
        powder = self.powder(scenario.bin_type, scenario.dirty, scenario.powder_amount, scenario.seed)
        if washes:
            from dataclasses import replace

            powder = replace(powder, washes=list(washes))  # the cached field stays unwashed
        return self._render(
            scenario.bin_type,
            T_world_bin,
            T_world_base,
            q,
            np.asarray(T_world_cam, dtype=float),
            intrinsics,
            params or RenderParams(),
            seed,
            powder,
            cell,
        )

    def render_bin_view(
        self,
        bin_type: str,
        T_bin_cam: ArrayLike,
        intrinsics: CameraLike,
        *,
        dirty: bool,
        powder_amount: float = 0.5,
        seed: int = 0,
        params: RenderParams | None = None,
        cell: bool = True,
    ) -> RenderResult:
        """Render a bin standing at the cabin centre from a camera pose in the bin frame (no robot)."""
        sc = Scenario(bin_type=bin_type, dirty=dirty, powder_amount=powder_amount, seed=seed)
        T_world_bin = sc.T_world_bin(self.catalog.get(bin_type))
        powder = self.powder(bin_type, dirty, powder_amount, seed)
        return self._render(
            bin_type,
            T_world_bin,
            None,
            None,
            T_world_bin @ np.asarray(T_bin_cam, dtype=float),
            intrinsics,
            params or RenderParams(),
            seed,
            powder,
            cell,
        )

    def _render(
        self,
        name: str,
        T_world_bin: NDArray,
        T_world_base: NDArray | None,
        q: NDArray | None,
        T_world_cam: NDArray,
        K: CameraLike,
        P: RenderParams,
        seed: int,
        powder: PowderField,
        cell: bool,
    ) -> RenderResult:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        if K.width * K.height > 4096 * 4096:
            raise ConfigError(f"render size {K.width}x{K.height} is too large; expected at most 4096x4096")
        V, F, M, T_world_board = self._scene(name, T_world_bin, T_world_base, q, cell)
        # Embree directly (not trimesh's wrapper): one first-hit query, distance + triangle id
        embree = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=embree, vertices=V.astype(np.float32), indices=F.astype(np.int32))
        W_, H_ = K.width, K.height
        n_pix = W_ * H_
        d_cam = self._ray_dirs(K)
        R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
        R32, o32 = R.T.astype(np.float32), o.astype(np.float32)
        rgb = np.empty((n_pix, 3), dtype=np.uint8)
        depth = np.full(n_pix, np.inf, dtype=np.float32)
        surface = np.full(n_pix, -1, dtype=np.int8)
        pmask = np.zeros(n_pix, dtype=bool)
        # one generator drawn tile after tile gives the same noise as one whole-frame draw
        rng = np.random.default_rng([seed, 31337])
        for a in range(0, n_pix, TILE_PIXELS):
            b = min(a + TILE_PIXELS, n_pix)
            dirs = d_cam[a:b] @ R32
            origins = np.broadcast_to(o32, dirs.shape)
            res = embree.run(np.ascontiguousarray(origins), dirs, output=1)
            hit = np.flatnonzero(res["primID"] >= 0)
            # background (beyond the cabin, or no cell): dim grey
            col = np.full((b - a, 3), 0.08)
            if len(hit):
                tri = res["primID"][hit].astype(np.int64)
                d = dirs[hit]
                p = o + d.astype(np.float64) * res["tfar"][hit, None].astype(np.float64)
                ids = a + hit
                depth[ids] = np.einsum("ij,ij->i", p - o, np.broadcast_to(R[:, 2], p.shape))
                col[hit], surf, powder_seen = self._shade(
                    name, V[F[tri]], M[tri], p, d, T_world_bin, T_world_board, P, powder
                )
                surface[ids] = surf
                pmask[ids] = powder_seen
            img = np.clip(col * P.exposure, 0, 1) ** (1 / 2.2) * 255.0
            if P.noise_sigma > 0:
                img = img + rng.normal(0, P.noise_sigma, img.shape)
            rgb[a:b] = np.clip(img, 0, 255).astype(np.uint8)
        return RenderResult(
            rgb.reshape(H_, W_, 3), pmask.reshape(H_, W_), surface.reshape(H_, W_), depth.reshape(H_, W_)
        )

    def _shade(
        self,
        name: str,
        tri_v: NDArray[np.float64],
        mat: NDArray[np.int8],
        p: NDArray[np.float64],
        d: NDArray[np.float32],
        T_world_bin: NDArray[np.float64],
        T_world_board: NDArray[np.float64],
        P: RenderParams,
        powder: PowderField,
    ) -> tuple[NDArray[np.float64], NDArray[np.int8], NDArray[np.bool_]]:
        """Linear colour (M, 3), surface tag (M,) and powder-seen flag (M,) of M ray hits.

        ``tri_v`` (M, 3, 3) are the hit triangles' corners, ``mat`` their materials, ``p`` the hit
        points and ``d`` the unit ray directions, all in the world frame.
        """
        surface = np.full(len(p), -1, dtype=np.int8)
        pmask = np.zeros(len(p), dtype=bool)
        face_n = np.cross(tri_v[:, 1] - tri_v[:, 0], tri_v[:, 2] - tri_v[:, 0])
        face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-300)
        fn = np.where((np.einsum("ij,ij->i", face_n, d) > 0)[:, None], -face_n, face_n)
        lights = np.array([[1.0, -1.2, 2.8], [-1.2, 0.8, 2.8]]) + np.asarray(P.light_offset)
        diffuse = np.zeros(len(p))
        spec_b = np.zeros(len(p))
        spec_p = np.zeros(len(p))
        for L in lights:
            ldir = L - p
            dist = np.linalg.norm(ldir, axis=1)
            ldir /= dist[:, None]
            att = P.light_scale * 0.55 * (3.0 / (1.0 + dist**2 / 4.0))
            ndl = np.clip(np.einsum("ij,ij->i", fn, ldir), 0, None)
            diffuse += att * ndl
            hv = ldir - d
            hv /= np.linalg.norm(hv, axis=1, keepdims=True)
            ndh = np.clip(np.einsum("ij,ij->i", fn, hv), 0, None)
            spec_b += att * ndh**18
            spec_p += att * ndh**400
        light = P.ambient + diffuse
        c = np.zeros((len(p), 3))
        # simple materials
        c[mat == M_FLOOR] = 0.35
        fl = mat == M_FLOOR
        if fl.any():
            chk = (np.floor(p[fl, 0] / 0.5) + np.floor(p[fl, 1] / 0.5)) % 2
            c[fl] = (0.30 + 0.08 * chk)[:, None] * np.array([1.0, 1.0, 0.95])
        c[mat == M_WALL] = np.array([0.62, 0.66, 0.70])
        c[mat == M_BASE] = np.array([0.20, 0.22, 0.25])
        c[mat == M_ROBOT] = np.array([0.72, 0.76, 0.80])
        c[mat == M_CAMERA] = np.array([0.10, 0.10, 0.12])
        col_hit = c * light[:, None]
        # board texture
        bd = mat == M_BOARD
        if bd.any():
            tex = self._board_texture(name)
            bt = self.catalog.get(name)
            w, h = bt.board.size_m
            pb = (p[bd] - T_world_board[:3, 3]) @ T_world_board[:3, :3]
            ty = np.clip((pb[:, 1] / h * tex.shape[0]).astype(int), 0, tex.shape[0] - 1)
            tx = np.clip((pb[:, 0] / w * tex.shape[1]).astype(int), 0, tex.shape[1] - 1)
            alb = 0.04 + 0.82 * tex[ty, tx]
            col_hit[bd] = (alb * light[bd])[:, None] * np.array([1.0, 1.0, 0.98])
        # stainless steel, both finishes, in the bin frame
        st = (mat == M_BIN_EXT) | (mat == M_BIN_INT)
        if st.any():
            Tbw = invert(T_world_bin)
            pbin = p[st] @ Tbw[:3, :3].T + Tbw[:3, 3]
            nbin = fn[st] @ Tbw[:3, :3].T
            horiz = np.abs(nbin[:, 2]) > 0.7
            coord = np.where(horiz, pbin[:, 1], pbin[:, 2])  # grain: around the walls, along x on plates
            streak = 0.6 * _STREAKS(coord, 0.00035) + 0.4 * _STREAKS(coord + 3.1, 0.0021)
            ext = mat[st] == M_BIN_EXT
            inn = ~ext
            lig = light[st]
            val = np.empty(len(lig))
            # brushed: grey albedo with streaks, broad specular stretched by the grain
            if ext.any():
                wav = value_noise3(pbin[ext] / 0.15, 99) - 0.5
                se = streak[ext]
                spec = 0.55 * spec_b[st][ext] * (1 + 0.5 * se)
                val[ext] = (0.50 + 0.07 * se + 0.05 * wav) * lig[ext] + spec
            # polished: reflect a synthetic cabin (bright ceiling, light panels) + sharp highlight
            if inn.any():
                dd = d[st][inn]
                nn = fn[st][inn]
                r = dd - 2 * np.einsum("ij,ij->i", dd, nn)[:, None] * nn
                env = 0.10 + 0.35 * np.clip(r[:, 2], 0, 1) ** 2
                panels = (np.abs(np.sin(r[:, 0] * 4.0 + r[:, 1] * 1.5)) > 0.92) & (r[:, 2] > 0.3)
                env = env + 0.9 * panels + 0.05 * (value_noise3(r * 3.0, 5) - 0.5)
                val[inn] = 0.16 * lig[inn] + 0.75 * env + 2.5 * spec_p[st][inn] + 0.02 * streak[inn]
            tint = np.array([0.97, 0.99, 1.02])
            sc = val[:, None] * tint
            # powder: matte, covers the steel
            a = powder.alpha(pbin, np.where(ext, EXTERNAL, INTERNAL), nbin)
            if a.any():
                prgb = np.asarray(P.powder_rgb) * (0.25 + 0.9 * lig)[:, None]
                sc = sc * (1 - a[:, None]) + prgb * a[:, None]
            col_hit[st] = sc
            surface[st] = np.where(ext, EXTERNAL, INTERNAL)
            pmask[st] = a > 0.5
        return col_hit, surface, pmask
