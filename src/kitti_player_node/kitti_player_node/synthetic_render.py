"""Exact ray-casting renderer and label computation for synthetic KITTI scenes.

Every pixel's ray (pixel centres at integer coordinates, the KITTI convention) is intersected
with the ground plane, the wall planes along the road, the vehicles (each a body box plus a cabin
box, slab test in the box frame) and a background at infinity; the nearest hit wins (z-buffer)
and an id buffer records which vehicle a pixel shows. Textures are functions of the 3D hit point
(ripmapped periodic noise sampled with the pixel footprint, box-filtered stripes), so the left
and right images see the same surfaces and stereo correspondences are true.

Labels follow KITTI: 3D box (h, w, l; bottom centre in camera 0; rotation_y), alpha, the 2D box
as the projection of the 3D box clipped to the image, truncation = fraction of the unclipped
projected box outside the image, and an occlusion level from the rendering: the fraction of the
vehicle's own in-image silhouette that is visible in the id buffer (>= 0.8 -> 0 fully visible,
>= 0.4 -> 1 partly occluded, else 2 largely occluded). A vehicle becomes a DontCare row (2D box
only, track id -1) when its 2D box is under 15 px high, it is beyond 70 m, or the projection of
its 3D centre falls outside its clipped 2D box (cut off by the image border); vehicles showing
fewer than 12 pixels (hidden, behind the camera, outside the view) get no row at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from vehicle_common.box3d import project_points, projected_bbox
from vehicle_common.kitti import DONTCARE, Calibration, KittiObject, alpha_from_rotation_y

from .synthetic_scene import (
    BUILDING,
    CAMERA_HEIGHT,
    CROSS_HALF_WIDTH,
    GAP,
    LANE_WIDTH,
    PARKING_LEFT,
    PARKING_RIGHT,
    ROAD_LEFT,
    ROAD_RIGHT,
    WALL_LEFT,
    WALL_RIGHT,
    Scene,
    Vehicle,
)

OCCLUSION_VISIBLE_0 = 0.8  # visible fraction of the silhouette for "fully visible"
OCCLUSION_VISIBLE_1 = 0.4  # ... for "partly occluded"; below: "largely occluded"
DONTCARE_MIN_HEIGHT_PX = 15.0  # smaller 2D boxes become DontCare rows
DONTCARE_MAX_DEPTH = 70.0  # farther vehicles become DontCare rows
MIN_VISIBLE_PX = 12  # vehicles showing fewer pixels are not labelled at all

GROUND_CLEARANCE = 0.17  # m between the road and the underbody
WHEEL_POS = 0.33  # wheel centres at +-WHEEL_POS * l from the box centre
SKY_ID, GROUND_ID, WALL_ID0, VEHICLE_ID0 = -1, -2, -10, 0  # values of the id buffer


def wheel_radius(vehicle: Vehicle) -> float:
    """Wheel radius of a vehicle (m)."""
    return min(0.34, 0.45 * vehicle.shape.body_height * vehicle.dimensions[0])


# ----------------------------------------------------------------------------- textures


class Ripmap:
    """A periodic square texture with box-filtered versions at every (u, v) scale pair.

    ``sample`` picks, per pixel, the level whose texel size matches the pixel footprint along
    each texture axis (anisotropic filtering for surfaces seen at grazing angles).
    """

    def __init__(self, texture: np.ndarray) -> None:
        n = texture.shape[0]
        self.n = n
        self.levels = int(math.log2(n)) - 1
        blocks, offsets, pos = [], np.zeros((self.levels, self.levels), np.int64), 0
        for lv in range(self.levels):
            for lu in range(self.levels):
                img = texture.reshape(n >> lv, 1 << lv, n >> lu, 1 << lu).mean(axis=(1, 3))
                offsets[lv, lu] = pos
                blocks.append(img.astype(np.float32).ravel())
                pos += img.size
        self.flat = np.concatenate(blocks)
        self.offsets = offsets

    def sample(self, s, t, log_fs, log_ft, texel: float) -> np.ndarray:
        """Texture at surface coordinates (s, t) (metres) for a texel size ``texel`` (metres),
        with pixel footprints given as log2 of metres along s and t."""
        shift = math.log2(texel)
        top = self.levels - 1
        lu = np.clip(np.rint(log_fs - shift), 0, top).astype(np.int64)
        lv = np.clip(np.rint(log_ft - shift), 0, top).astype(np.int64)
        wu = self.n >> lu
        si = (np.floor(s * (1.0 / texel)).astype(np.int64) >> lu) & (wu - 1)
        ti = (np.floor(t * (1.0 / texel)).astype(np.int64) >> lv) & ((self.n >> lv) - 1)
        return self.flat[self.offsets[lv, lu] + ti * wu + si]


def noise_texture(rng: np.random.Generator, n: int, beta: float) -> np.ndarray:
    """Periodic n x n noise with a 1/f**beta amplitude spectrum, zero mean, unit std."""
    F = np.fft.fft2(rng.standard_normal((n, n)))
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(n) * n, np.fft.fftfreq(n) * n))
    f[0, 0] = 1.0
    F = F / f**beta
    F[0, 0] = 0.0
    tex = np.real(np.fft.ifft2(F))
    return (tex - tex.mean()) / tex.std()


def pulses(s, footprint, period: float, start: float, width: float):
    """Box-filtered periodic pulse train: coverage in [0, 1] of [start, start + width) mod period
    over a pixel footprint centred at ``s`` (anti-aliased stripes, dashes, windows)."""

    def integral(x):
        k = np.floor(x / period)
        r = x - k * period
        return k * width + np.clip(r - start, 0.0, width)

    fp = np.maximum(footprint, 1e-4)
    return (integral(s + fp / 2) - integral(s - fp / 2)) / fp


def band(s, footprint, lo: float, hi: float):
    """Box-filtered coverage of the interval [lo, hi) over a footprint centred at ``s``."""
    fp = np.maximum(footprint, 1e-4)
    a = np.clip(s - fp / 2, lo, hi)
    b = np.clip(s + fp / 2, lo, hi)
    return (b - a) / fp


# ----------------------------------------------------------------------------- camera


class CameraRays:
    """Per-pixel rays of one rectified camera and its static intersections with the ground and
    the wall planes (the ego car only translates along z, so these hold for every frame)."""

    def __init__(self, P: np.ndarray, width: int, height: int, walls) -> None:
        K = P[:, :3]
        self.P = P
        self.centre = -np.linalg.solve(K, P[:, 3])  # camera centre in camera-0 coordinates
        self.fx, self.fy = float(K[0, 0]), float(K[1, 1])
        u = np.arange(width, dtype=np.float64)
        v = np.arange(height, dtype=np.float64)
        self.dx = np.broadcast_to(((u - K[0, 2]) / self.fx)[None, :], (height, width))
        self.dy = np.broadcast_to(((v - K[1, 2]) / self.fy)[:, None], (height, width))
        self.shape = (height, width)
        cx, cy = self.centre[0], self.centre[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            # ground y = CAMERA_HEIGHT
            hg = CAMERA_HEIGHT - cy
            tg = np.where(self.dy > 1e-9, hg / self.dy, np.inf)
            self.ground_t = tg
            self.ground_ids = np.where(np.isfinite(tg), GROUND_ID, SKY_ID).astype(np.int32)
            self.ground_x = cx + tg * self.dx
            self.ground_fx = np.maximum(tg / self.fx, np.abs(self.dx) * tg * tg / (hg * self.fy))
            self.ground_fz = tg * tg / (hg * self.fy)
            # flat float32 copies for shading, with log2 footprints (static mip levels)
            f32 = np.float32
            self.flat_ground = (
                self.ground_x.astype(f32).ravel(),
                tg.astype(f32).ravel(),
                self.ground_fx.astype(f32).ravel(),
                self.ground_fz.astype(f32).ravel(),
                np.log2(self.ground_fx).astype(f32).ravel(),
                np.log2(self.ground_fz).astype(f32).ravel(),
            )
            self.walls = []
            for wall in walls:
                ox = wall.x - cx
                tw = np.where(self.dx * ox > 0, ox / self.dx, np.inf)
                cand = np.isfinite(tw) & (tw < tg) & (cy + tw * self.dy > -40.0)
                idx = np.flatnonzero(cand)
                t = tw.ravel()[idx]
                y = cy + t * self.dy.ravel()[idx]
                fz = t * t / (abs(ox) * self.fx)
                fy = np.maximum(t / self.fy, np.abs(self.dy.ravel()[idx]) * fz)
                lfz, lfy = np.log2(fz).astype(f32), np.log2(fy).astype(f32)
                self.walls.append(
                    (wall, idx, t, y.astype(f32), fz.astype(f32), fy.astype(f32), lfz, lfy)
                )


@dataclass
class RenderResult:
    """One rendered view: RGB float image in [0, 1], depth (camera z, m) and id buffer, and per
    vehicle (track id) its silhouette pixel count (in the image, ignoring other objects)."""

    image: np.ndarray
    depth: np.ndarray
    ids: np.ndarray
    silhouette: dict[int, int]


# ----------------------------------------------------------------------------- renderer


class StereoRenderer:
    """Renders the left (P2) and right (P3) views of a :class:`Scene` and computes its labels."""

    def __init__(self, scene: Scene, calib: Calibration, width: int, height: int) -> None:
        self.scene, self.calib = scene, calib
        self.sun = np.asarray(scene.sun, float) / np.linalg.norm(scene.sun)
        self.width, self.height = width, height
        rng = np.random.default_rng([scene.seed, 0x7E57])
        self.tex_fine = Ripmap(noise_texture(rng, 256, 0.6))
        self.tex_pink = Ripmap(noise_texture(rng, 256, 1.0))
        self.tex_leaf = Ripmap(noise_texture(rng, 256, 0.3))
        self.cameras = [
            CameraRays(calib.P2, width, height, scene.walls),
            CameraRays(calib.P3, width, height, scene.walls),
        ]
        self._sky = [self._sky_colour(c) for c in self.cameras]

    # -- background --------------------------------------------------------------------------

    def _sky_colour(self, cam: CameraRays) -> np.ndarray:
        h, w = cam.shape
        elev = -cam.dy  # > 0 above the horizon
        base_lo = np.array([0.80, 0.84, 0.88], np.float32)
        base_hi = np.array([0.45, 0.62, 0.85], np.float32)
        a = np.clip(elev / 0.35, 0.0, 1.0)[..., None]
        sky = base_lo * (1 - a) + base_hi * a
        # clouds and a far hill line, both at infinity (identical in both views)
        ang_u = np.arctan(cam.dx) * 600.0
        ang_v = np.arctan(cam.dy) * 600.0
        clouds = self.tex_pink.sample(ang_u, ang_v * 2.0, 0.0, 0.0, 1.0)
        sky = sky + 0.06 * clouds[..., None]
        hill = 0.04 + 0.03 * self.tex_pink.sample(ang_u * 0.3, 7.0, 0.0, 0.0, 1.0)
        hill_mask = (elev < hill)[..., None]
        tree = 0.25 + 0.08 * self.tex_leaf.sample(ang_u * 4.0, ang_v * 4.0, 0.0, 0.0, 1.0)
        hills = np.stack([tree * 0.8, tree, tree * 0.7], axis=-1)
        return np.where(hill_mask, hills, sky).astype(np.float32)

    def _shade_ground(self, X, Z, fx, fz, lfx, lfz) -> np.ndarray:
        tex, pink = self.tex_fine, self.tex_pink
        n1 = tex.sample(X, Z, lfx, lfz, 0.015)
        n2 = pink.sample(X, Z, lfx, lfz, 0.12)
        grey = 0.34 + 0.05 * n1 + 0.04 * n2
        in_cross = np.abs(Z - self.scene.junction_z) < CROSS_HALF_WIDTH
        # lane markings on the carriageway (not across the junction)
        mark = np.zeros_like(X)
        dash = pulses(Z, fz, 9.0, 0.0, 3.0)
        for xb in (ROAD_LEFT + LANE_WIDTH, ROAD_LEFT + 3 * LANE_WIDTH):
            mark = np.maximum(mark, band(X, fx, xb - 0.075, xb + 0.075) * dash)
        xc = ROAD_LEFT + 2 * LANE_WIDTH
        mark = np.maximum(mark, band(X, fx, xc - 0.2, xc - 0.08))
        mark = np.maximum(mark, band(X, fx, xc + 0.08, xc + 0.2))
        mark = np.maximum(mark, band(X, fx, ROAD_LEFT + 0.15, ROAD_LEFT + 0.3))
        mark = np.maximum(mark, band(X, fx, ROAD_RIGHT - 0.3, ROAD_RIGHT - 0.15))
        mark = np.where(in_cross, 0.0, mark)
        value = grey * (1 - mark) + (0.85 + 0.05 * n1) * mark
        rgb = np.stack([value, value, value * 1.02], axis=-1)
        # sidewalks with paving tiles, except across the junction; grass beyond the walls
        side = ((X < PARKING_LEFT) | (X > PARKING_RIGHT)) & ~in_cross
        if side.any():
            xs, zs, fxs, fzs = X[side], Z[side], fx[side], fz[side]
            lxs, lzs = lfx[side], lfz[side]
            joints = np.maximum(pulses(xs, fxs, 0.6, 0.0, 0.04), pulses(zs, fzs, 0.6, 0.0, 0.04))
            ns = self.tex_fine.sample(xs, zs, lxs, lzs, 0.01)
            pv = 0.55 + 0.05 * ns - 0.25 * joints
            paving = np.stack([pv, pv * 0.97, pv * 0.92], axis=-1)
            outside = (xs < WALL_LEFT) | (xs > WALL_RIGHT)
            g = 0.3 + 0.08 * self.tex_leaf.sample(xs, zs, lxs, lzs, 0.03)
            grass = np.stack([g * 0.6, g, g * 0.4], axis=-1)
            rgb[side] = np.where(outside[:, None], grass, paving)
        return rgb

    def _shade_wall(self, wall, seg, Z, Y, fz, fy, lfz, lfy) -> np.ndarray:
        up = CAMERA_HEIGHT - Y  # height above ground
        out = np.empty((len(Z), 3), np.float32)
        b = wall.kinds[seg] == BUILDING
        for is_building, sel in ((True, np.flatnonzero(b)), (False, np.flatnonzero(~b))):
            if not len(sel):
                continue
            zs, us, lz, ly, sg = Z[sel], up[sel], lfz[sel], lfy[sel], seg[sel]
            base = wall.colours[sg]
            n = self.tex_pink.sample(zs, us, lz, ly, 0.05)
            if is_building:
                nf = self.tex_fine.sample(zs, us, lz, ly, 0.02)
                period = wall.window_period[sg]
                # windows: one per period along z, one row per 3 m floor
                wz = pulses(zs / period, fz[sel] / period, 1.0, 0.3, 0.45)
                wy = pulses(us, fy[sel], 3.0, 0.9, 1.4)
                win = (wz * wy * (us > 0.5))[:, None]
                facade = base * (1.0 + 0.10 * n + 0.05 * nf)[:, None]
                glass = (0.18 + 0.06 * n)[:, None] * np.array([0.8, 0.9, 1.1], np.float32)
                out[sel] = facade * (1 - win) + glass * win
            else:
                leaf = self.tex_leaf.sample(zs, us, lz, ly, 0.04)
                out[sel] = base * (1.0 + 0.35 * leaf + 0.1 * n)[:, None]
        return out

    # -- vehicles ---------------------------------------------------------------------------

    def vehicle_pose(self, vehicle: Vehicle, frame: int) -> tuple[np.ndarray, float]:
        """Bottom-centre location (camera 0 at ``frame``) and rotation_y of a vehicle."""
        x, z, ry = vehicle.state(self.scene.time(frame))
        return np.array([x, CAMERA_HEIGHT, z - self.scene.ego_z(frame)]), ry

    def _vehicle_hits(self, cam: CameraRays, vehicle: Vehicle, loc, ry, window):
        """Ray/box intersections of a vehicle (body and cabin) in an image window."""
        v0, v1, u0, u1 = window
        h, w, length = vehicle.dimensions
        sh = vehicle.shape
        c, s = math.cos(ry), math.sin(ry)
        o = cam.centre - loc
        ox, oy, oz = c * o[0] - s * o[2], o[1], s * o[0] + c * o[2]
        dxw = cam.dx[v0:v1, u0:u1]
        dyw = cam.dy[v0:v1, u0:u1]
        ldx = c * dxw - s
        ldz = s * dxw + c
        ldy = np.broadcast_to(dyw, dxw.shape)
        hb = sh.body_height * h
        lc = sh.cabin_length * length
        xc = sh.cabin_offset * length
        wc = sh.cabin_width * w
        wr = wheel_radius(vehicle)
        parts = [
            ((-length / 2, length / 2), (-hb, -GROUND_CLEARANCE), (-w / 2, w / 2)),
            ((xc - lc / 2, xc + lc / 2), (-h, -hb), (-wc / 2, wc / 2)),
        ]
        for xw in (WHEEL_POS * length, -WHEEL_POS * length):
            for zw in ((w / 2 - 0.25, w / 2 - 0.03), (-w / 2 + 0.03, -w / 2 + 0.25)):
                parts.append(((xw - wr, xw + wr), (-2 * wr, 0.0), zw))
        best_t = np.full(dxw.shape, np.inf)
        best_axis = np.zeros(dxw.shape, np.int8)
        best_part = np.zeros(dxw.shape, np.int8)
        P, H, W = cam.P, v1 - v0, u1 - u0
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = [1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d) for d in (ldx, ldy, ldz)]
            for k, bounds in enumerate(parts):
                # the part's own pixel window inside the vehicle's window
                (x0, x1), (y0, y1), (z0, z1) = bounds
                cx_ = np.array([x0, x1, x0, x1, x0, x1, x0, x1])
                cy_ = np.array([y0, y0, y1, y1, y0, y0, y1, y1])
                cz_ = np.array([z0, z0, z0, z0, z1, z1, z1, z1])
                corners = np.stack(
                    [loc[0] + c * cx_ + s * cz_, loc[1] + cy_, loc[2] - s * cx_ + c * cz_], axis=1
                )
                a0, a1, b0, b1 = 0, H, 0, W
                if corners[:, 2].min() > 0.1:
                    uv = project_points(P, corners)
                    b0 = max(int(math.floor(uv[:, 0].min())) - 1 - u0, 0)
                    b1 = min(int(math.ceil(uv[:, 0].max())) + 2 - u0, W)
                    a0 = max(int(math.floor(uv[:, 1].min())) - 1 - v0, 0)
                    a1 = min(int(math.ceil(uv[:, 1].max())) + 2 - v0, H)
                    if a1 <= a0 or b1 <= b0:
                        continue
                sl = (slice(a0, a1), slice(b0, b1))
                tmins, tmaxs = [], []
                for (lo, hi), oo, iv in zip(bounds, (ox, oy, oz), inv, strict=True):
                    t1, t2 = (lo - oo) * iv[sl], (hi - oo) * iv[sl]
                    tmins.append(np.minimum(t1, t2))
                    tmaxs.append(np.maximum(t1, t2))
                tn = np.maximum(np.maximum(tmins[0], tmins[1]), tmins[2])
                tf = np.minimum(np.minimum(tmaxs[0], tmaxs[1]), tmaxs[2])
                bt = best_t[sl]
                hit = (tn <= tf) & (tn > 0.05) & (tn < bt)
                if not hit.any():
                    continue
                axis = np.where(tmins[0] >= tn, 0, np.where(tmins[1] >= tn, 1, 2))
                bt[hit] = tn[hit]
                best_axis[sl][hit] = axis[hit]
                best_part[sl][hit] = min(k, 2)
        with np.errstate(invalid="ignore"):  # inf * 0 where no box is hit (a ray along an axis)
            local = (ox + best_t * ldx, oy + best_t * ldy, oz + best_t * ldz)
        sign = np.where(
            best_axis == 0, -np.sign(ldx), np.where(best_axis == 1, -np.sign(ldy), -np.sign(ldz))
        )
        return best_t, best_axis, best_part, sign, local, (c, s)

    def _shade_vehicle(self, vehicle, sel, t, axis, part, sign, local, rot, fx) -> np.ndarray:
        h, w, length = vehicle.dimensions
        sh = vehicle.shape
        lx, ly, lz = (a[sel] for a in local)
        ax, pt, sg, tt = axis[sel], part[sel], sign[sel], t[sel]
        c, s = rot
        # normal in camera coordinates
        nlx = np.where(ax == 0, sg, 0.0)
        nly = np.where(ax == 1, sg, 0.0)
        nlz = np.where(ax == 2, sg, 0.0)
        ncx, ncz = c * nlx + s * nlz, -s * nlx + c * nlz
        sun = self.sun
        lam = np.maximum(0.0, ncx * sun[0] + nly * sun[1] + ncz * sun[2])
        light = (0.45 + 0.6 * lam).astype(np.float32)
        base = np.asarray(vehicle.colour, np.float32)
        up = -ly  # height above ground
        # surface coordinates for texture: along-face horizontal and vertical
        su = np.where(ax == 0, lz, lx)
        sv = np.where(ax == 1, lz, up)
        lfp = np.log2(tt / fx)
        n = self.tex_pink.sample(su + 0.7 * vehicle.track_id, sv, lfp, lfp, 0.02)
        body = base[None, :] * (1.0 + 0.04 * n)[:, None]
        hb = sh.body_height * h
        side = ax == 2
        front = (ax == 0) & (sg > 0)
        rear = (ax == 0) & (sg < 0)
        cabin = pt == 1
        dark = np.array([0.05, 0.05, 0.055], np.float32)
        glass = np.array([0.10, 0.13, 0.17], np.float32)
        # glass on the cabin sides/front/rear, with pillars at the ends and a roof edge
        cab_lo = sh.cabin_offset * length - sh.cabin_length * length / 2
        cab_hi = sh.cabin_offset * length + sh.cabin_length * length / 2
        pillar = (lx < cab_lo + 0.12) | (lx > cab_hi - 0.12)
        wc = sh.cabin_width * w
        window = cabin & (ax != 1) & (up < h - 0.07) & (up > hb + 0.06)
        window &= ~(side & pillar) & ~((ax == 0) & (np.abs(lz) > wc / 2 - 0.08))
        refl = 0.05 * (up - hb) / max(h - hb, 1e-3)
        colour = body
        colour = np.where(window[:, None], glass + refl[:, None] + 0.02 * n[:, None], colour)
        # lower band (sills, bumpers) darker
        lower = (up < 0.28) & ~cabin
        colour = np.where(lower[:, None], colour * 0.35 + 0.03, colour)
        # wheels: tyre arcs on the body sides, tyres (part 2) below the body, grey rims
        wr = wheel_radius(vehicle)
        wheel = pt == 2
        for xw in (WHEEL_POS * length, -WHEEL_POS * length):
            d2 = (lx - xw) ** 2 + (up - wr) ** 2
            tyre = side & (d2 < wr * wr)
            rim = side & (d2 < (0.55 * wr) ** 2)
            colour = np.where((tyre | wheel)[:, None], dark + 0.02 * n[:, None], colour)
            colour = np.where(rim[:, None], np.float32(0.45) + 0.05 * n[:, None], colour)
        # lights and grille
        lamp_y = (up > hb - 0.25) & (up < hb - 0.08) & ~cabin
        lamp_z = (np.abs(lz) > w / 2 - 0.45) & (np.abs(lz) < w / 2 - 0.08)
        head = front & lamp_y & lamp_z
        tail = rear & lamp_y & lamp_z
        grille = front & (up > 0.3) & (up < hb - 0.1) & (np.abs(lz) < w / 2 - 0.5)
        colour = np.where(head[:, None], np.array([0.95, 0.93, 0.80], np.float32), colour)
        colour = np.where(tail[:, None], np.array([0.75, 0.05, 0.04], np.float32), colour)
        colour = np.where(grille[:, None], colour * 0.3, colour)
        plate = (front | rear) & (np.abs(lz) < 0.26) & (up > 0.35) & (up < 0.46)
        colour = np.where(plate[:, None], np.array([0.9, 0.9, 0.88], np.float32), colour)
        return (colour * light[:, None]).astype(np.float32)

    def _window(self, P, dimensions, loc, ry, pad: int = 1):
        """Integer pixel window (v0, v1, u0, u1) covering a projected box, or None."""
        box = projected_bbox(P, dimensions, loc, ry, (self.width, self.height))
        return None if box is None else self._box_window(box, pad)

    def _box_window(self, box, pad: int = 1):
        """Integer pixel window (v0, v1, u0, u1) covering the image-clipped 2D ``box``."""
        x1, y1, x2, y2 = box
        u0, v0 = max(int(math.floor(x1)) - pad, 0), max(int(math.floor(y1)) - pad, 0)
        u1 = min(int(math.ceil(x2)) + pad + 1, self.width)
        v1 = min(int(math.ceil(y2)) + pad + 1, self.height)
        return v0, v1, u0, u1

    # -- frame ------------------------------------------------------------------------------

    def render(self, frame: int, camera: int) -> RenderResult:
        """Render view ``camera`` (0 = left/P2, 1 = right/P3) of ``frame``."""
        cam = self.cameras[camera]
        H, W = cam.shape
        ez = self.scene.ego_z(frame)
        img = self._sky[camera].copy()
        depth = cam.ground_t.copy()  # inf above the horizon
        ids = cam.ground_ids.copy()
        dflat, iflat = depth.reshape(-1), ids.reshape(-1)
        wall_hits = []
        for k, (wall, idx, t, y, fz, fy, lfz, lfy) in enumerate(cam.walls):
            Z = t + ez
            seg = wall.index(Z)
            ok = (wall.kinds[seg] != GAP) & (y >= CAMERA_HEIGHT - wall.heights[seg])
            ok &= t < dflat[idx]
            sel = idx[ok]
            dflat[sel] = t[ok]
            iflat[sel] = WALL_ID0 - k
            wall_hits.append((wall, ok, seg, Z, y, fz, fy, lfz, lfy, idx))
        # shade the visible background
        flat = img.reshape(-1, 3)
        gsel = np.flatnonzero(iflat == GROUND_ID)
        gx, gt, gfx, gfz, glx, glz = (a[gsel] for a in cam.flat_ground)
        flat[gsel] = self._shade_ground(gx, gt + np.float32(ez), gfx, gfz, glx, glz)
        for k, (wall, ok, seg, Z, y, fz, fy, lfz, lfy, idx) in enumerate(wall_hits):
            keep = np.flatnonzero(ok & (iflat[idx] == WALL_ID0 - k))
            normal_x = 1.0 if wall.x < 0 else -1.0  # walls face the road
            light = np.float32(0.6 + 0.5 * max(0.0, normal_x * self.sun[0]))
            flat[idx[keep]] = light * self._shade_wall(
                wall,
                seg[keep],
                Z[keep].astype(np.float32),
                y[keep],
                fz[keep],
                fy[keep],
                lfz[keep],
                lfy[keep],
            )
        # vehicles: shadows on the ground, then z-buffered boxes
        poses = [self.vehicle_pose(v, frame) for v in self.scene.vehicles]
        for v, (loc, ry) in zip(self.scene.vehicles, poses, strict=True):
            self._shadow(cam, v, loc, ry, img, ids, ez)
        silhouette: dict[int, int] = {}
        for v, (loc, ry) in zip(self.scene.vehicles, poses, strict=True):
            win = self._window(cam.P, v.dimensions, loc, ry)
            if win is None:
                continue
            v0, v1, u0, u1 = win
            t, axis, part, sign, local, rot = self._vehicle_hits(cam, v, loc, ry, win)
            hit = np.isfinite(t)
            silhouette[v.track_id] = int(hit.sum())
            dz = depth[v0:v1, u0:u1]
            front = hit & (t < dz)
            if not front.any():
                continue
            dz[front] = t[front]
            ids[v0:v1, u0:u1][front] = VEHICLE_ID0 + v.track_id
            img[v0:v1, u0:u1][front] = self._shade_vehicle(
                v, front, t, axis, part, sign, local, rot, cam.fx
            )
        img *= np.float32(self.scene.exposure)
        return RenderResult(image=img, depth=depth, ids=ids, silhouette=silhouette)

    def _shadow(self, cam: CameraRays, v: Vehicle, loc, ry, img, ids, ez) -> None:
        h, w, length = v.dimensions
        flat_dims = (0.01, w + 0.5, length + 0.5)
        win = self._window(cam.P, flat_dims, loc, ry)
        if win is None:
            return
        v0, v1, u0, u1 = win
        g = ids[v0:v1, u0:u1] == GROUND_ID
        if not g.any():
            return
        X = cam.ground_x[v0:v1, u0:u1] - loc[0]
        Z = cam.ground_t[v0:v1, u0:u1] - loc[2]
        c, s = math.cos(ry), math.sin(ry)
        lx, lz = c * X - s * Z, s * X + c * Z
        fx = cam.ground_fz[v0:v1, u0:u1]
        cover = band(lx, fx, -length / 2 - 0.15, length / 2 + 0.15) * band(
            lz, fx, -w / 2 - 0.15, w / 2 + 0.15
        )
        factor = 1.0 - 0.55 * np.where(g, cover, 0.0)
        img[v0:v1, u0:u1] *= factor[..., None].astype(np.float32)

    # -- labels -----------------------------------------------------------------------------

    def labels(self, frame: int, left: RenderResult) -> list[KittiObject]:
        """KITTI tracking label rows of ``frame`` computed from its left rendering."""
        P2 = self.calib.P2
        size = (self.width, self.height)
        rows = []
        for v in self.scene.vehicles:
            loc, ry = self.vehicle_pose(v, frame)
            loc = tuple(round(float(c), 6) for c in loc)
            ry = round(ry, 6)
            box = projected_bbox(P2, v.dimensions, loc, ry, size)
            sil = left.silhouette.get(v.track_id, 0)
            if box is None or sil == 0:
                continue
            v0, v1, u0, u1 = self._box_window(box)
            visible = int((left.ids[v0:v1, u0:u1] == VEHICLE_ID0 + v.track_id).sum())
            if visible < MIN_VISIBLE_PX:
                continue
            full = projected_bbox(P2, v.dimensions, loc, ry)
            area_full = (full[2] - full[0]) * (full[3] - full[1])
            area_in = (box[2] - box[0]) * (box[3] - box[1])
            truncated = float(np.clip(1.0 - area_in / area_full, 0.0, 1.0))
            obj = KittiObject(
                type=v.type,
                dimensions=v.dimensions,
                location=loc,
                rotation_y=ry,
                bbox=tuple(round(b, 6) for b in box),
                frame=frame,
                track_id=v.track_id,
            )
            com = obj.centre_of_mass
            inside = False
            if com[2] > 0.5:
                cu, cv = project_points(P2, com[None, :])[0]
                inside = box[0] <= cu <= box[2] and box[1] <= cv <= box[3]
            if (
                not inside
                or box[3] - box[1] < DONTCARE_MIN_HEIGHT_PX
                or loc[2] > DONTCARE_MAX_DEPTH
            ):
                rows.append(dontcare_row(frame, obj.bbox))
                continue
            frac = visible / sil
            occluded = 0 if frac >= OCCLUSION_VISIBLE_0 else 1 if frac >= OCCLUSION_VISIBLE_1 else 2
            alpha = round(alpha_from_rotation_y(ry, loc[0], loc[2]), 6)
            rows.append(obj.with_(truncated=round(truncated, 4), occluded=occluded, alpha=alpha))
        return rows


def dontcare_row(frame: int, bbox) -> KittiObject:
    """A KITTI DontCare row (only the 2D box is meaningful)."""
    return KittiObject(
        type=DONTCARE,
        truncated=-1.0,
        occluded=-1,
        alpha=-10.0,
        bbox=tuple(bbox),
        dimensions=(-1.0, -1.0, -1.0),
        location=(-1000.0, -1000.0, -1000.0),
        rotation_y=-10.0,
        frame=frame,
        track_id=-1,
    )
