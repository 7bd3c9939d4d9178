"""Drawing a voxel satellite in a viser scene (a server's, a client's, or a recording's).

The scene is drawn in **module units**: one cube module (0.1 m in the default catalog) is
one scene unit, so a 3x3x3 satellite spans 3 units and viser's default camera frames it.
The body frame's origin is the centre of mass of the modules (all modules weigh the same),
as in the physics (docs/physics.md); viser's ``wxyz`` of a frame is exactly ``q_BN``.

Layout of one satellite under ``prefix`` (e.g. ``/A``)::

    prefix                 placement (side-by-side offset), not rotated
    prefix/body            frame, wxyz = q_BN, with the body axes (x red, y green, z blue)
    prefix/body/voxels     one batched mesh: the actuators, orange
    prefix/body/structure  one batched mesh: the structure modules, grey at opacity 0.2
                           (an actuator inside the satellite stays visible)
    prefix/body/payload    one batched mesh: the payload's cells (the spec's
                           ``modules.payload.cells`` or ``objective.payload_cells``),
                           blue-grey at opacity 0.7; absent when the run has no payload
    prefix/body/edges      cube edges (line segments)
    prefix/target          frame, wxyz = q_TN: the target attitude
    prefix/target/ghost    the same voxels at opacity 0.2
    prefix/label           the run's name, above the satellite
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from modsat_core.grid import ACTUATOR, EMPTY

if TYPE_CHECKING:  # viser is imported where a scene is drawn, not here
    from viser import FrameHandle

#: sRGB colours (0-255). The actuator colour is what the browser tests look for.
STRUCTURE_SRGB = (150, 150, 150)
ACTUATOR_SRGB = (255, 127, 14)  # #ff7f0e
#: The payload's cells: blue-grey, less translucent than structure, so the payload plate reads
#: as a part of its own while a wheel unit behind it still shows.
PAYLOAD_SRGB = (96, 125, 168)  # #607da8
#: Structure modules are drawn translucent so that enclosed actuators show.
STRUCTURE_OPACITY = 0.2
PAYLOAD_OPACITY = 0.7
EDGE_SRGB = (35, 35, 35)
GHOST_OPACITY = 0.2

#: Unit cube centred at the origin: 8 vertices, 12 outward (counter-clockwise) triangles.
CUBE_VERTICES = np.array([[x, y, z] for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)], dtype=np.float32)[
    [0, 1, 3, 2, 4, 5, 7, 6]
]
CUBE_FACES = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [3, 7, 6],
        [3, 6, 2],
        [0, 4, 7],
        [0, 7, 3],
        [1, 2, 6],
        [1, 6, 5],
    ],
    dtype=np.uint32,
)
_CUBE_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def srgb_to_linear(rgb) -> np.ndarray:
    """sRGB (0-255 or 0-1) -> linear RGB in [0, 1]; viser's batched colours are linear."""
    c = np.asarray(rgb, dtype=np.float64)
    if c.max(initial=0.0) > 1.0:
        c = c / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


@dataclass(frozen=True)
class Voxels:
    """The filled cells of a grid in body coordinates (module units)."""

    positions: np.ndarray  # (M, 3) float32, cell centres relative to the centre of mass
    types: np.ndarray  # (M,) int: STRUCTURE or ACTUATOR
    payload: np.ndarray | None = None  # (M,) bool: a payload cell (never an actuator); None: no payload

    @classmethod
    def from_grid(cls, grid, payload=None) -> Voxels:
        """The filled cells of ``grid``; ``payload`` lists the payload's cells [i, j, k] (those
        outside the grid, empty or holding a wheel unit are not marked)."""
        g = np.asarray(grid)
        cells = np.argwhere(g > EMPTY)
        if len(cells) == 0:
            return cls(np.zeros((0, 3), np.float32), np.zeros(0, np.int64))
        com = cells.mean(axis=0)
        types = g[tuple(cells.T)].astype(np.int64)
        marked = None
        if payload:
            wanted = {tuple(int(v) for v in c) for c in payload}
            marked = np.array([tuple(c) in wanted for c in cells.tolist()], dtype=bool) & (types < ACTUATOR)
        return cls((cells - com).astype(np.float32), types, marked)

    @property
    def is_payload(self) -> np.ndarray:
        """(M,) bool: the payload's cells (all False without a payload)."""
        return np.zeros(len(self.types), bool) if self.payload is None else self.payload

    @property
    def colors_linear(self) -> np.ndarray:
        """(M, 3) linear RGB in [0, 1]."""
        table = np.stack(
            [srgb_to_linear(STRUCTURE_SRGB), srgb_to_linear(STRUCTURE_SRGB), srgb_to_linear(ACTUATOR_SRGB)]
        )
        out = table[np.clip(self.types, 0, 2)]
        out[self.is_payload] = srgb_to_linear(PAYLOAD_SRGB)
        return out

    @property
    def radius(self) -> float:
        """Distance from the centre of mass to the farthest cube corner (module units)."""
        if not len(self.positions):
            return 0.5
        return float(np.linalg.norm(self.positions, axis=1).max() + np.sqrt(3) / 2)

    def edge_segments(self) -> np.ndarray:
        """(S, 2, 3) float32: the cube edges, each shared edge once."""
        if not len(self.positions):
            return np.zeros((0, 2, 3), np.float32)
        corners = self.positions[:, None, :] + CUBE_VERTICES[None]  # (M, 8, 3)
        idx = np.array(_CUBE_EDGES)
        seg = np.stack([corners[:, idx[:, 0]], corners[:, idx[:, 1]]], axis=2).reshape(-1, 2, 3)
        key = np.round(np.sort(seg, axis=1) * 2).astype(np.int64).reshape(len(seg), 6)  # order-free, exact on halves
        _, first = np.unique(key, axis=0, return_index=True)
        return seg[np.sort(first)].astype(np.float32)


@dataclass
class SatelliteHandles:
    """What a drawn satellite exposes for animation."""

    body: FrameHandle  # wxyz = q_BN
    target: FrameHandle  # wxyz = q_TN
    radius: float

    def set_attitude(self, q_BN, q_TN=None) -> None:
        self.body.wxyz = np.asarray(q_BN, dtype=np.float64)
        if q_TN is not None:
            self.target.wxyz = np.asarray(q_TN, dtype=np.float64)


def draw_satellite(
    scene,
    prefix: str,
    grid,
    *,
    position=(0.0, 0.0, 0.0),
    label: str | None = None,
    q_BN=(1.0, 0.0, 0.0, 0.0),
    q_TN=(1.0, 0.0, 0.0, 0.0),
    payload=None,
) -> SatelliteHandles:
    """Draw (or redraw, same names) the satellite of ``grid`` (N, N, N) under ``prefix``.

    ``scene`` is a viser ``SceneApi`` (``server.scene`` or ``client.scene``); ``payload`` the
    payload's cells [i, j, k] (``RunData.payload_cells``), drawn in their own colour."""
    vox = Voxels.from_grid(grid, payload)
    r = vox.radius
    axes = max(1.5, r + 0.8)
    scene.add_frame(prefix, show_axes=False, position=tuple(float(v) for v in position))
    body = scene.add_frame(
        f"{prefix}/body", axes_length=axes, axes_radius=0.05, origin_radius=0.08, wxyz=tuple(float(v) for v in q_BN)
    )
    target = scene.add_frame(
        f"{prefix}/target",
        axes_length=axes * 0.8,
        axes_radius=0.025,
        origin_radius=0.04,
        wxyz=tuple(float(v) for v in q_TN),
    )
    if len(vox.positions):
        M = len(vox.positions)
        ident = np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (M, 1))
        colors = vox.colors_linear.astype(np.float32)
        # Actuators opaque, structure translucent: a wheel unit inside the satellite (the
        # designs that fly best put the one actuator at the centre) stays visible. The payload
        # sits between the two, so that its plate stands out from the structure.
        act, pay = vox.types >= ACTUATOR, vox.is_payload
        parts = (
            ("voxels", act, None),
            ("payload", pay, PAYLOAD_OPACITY),
            ("structure", ~act & ~pay, STRUCTURE_OPACITY),
        )
        for name, sel, opacity in parts:
            if sel.any():
                scene.add_batched_meshes_simple(
                    f"{prefix}/body/{name}",
                    CUBE_VERTICES,
                    CUBE_FACES,
                    ident[sel],
                    vox.positions[sel],
                    batched_colors=colors[sel],
                    flat_shading=True,
                    opacity=opacity,
                )
            else:
                scene.remove_by_name(f"{prefix}/body/{name}")
        scene.add_line_segments(f"{prefix}/body/edges", vox.edge_segments(), srgb_to_linear(EDGE_SRGB), thickness=0.035)
        scene.add_batched_meshes_simple(
            f"{prefix}/target/ghost",
            CUBE_VERTICES * 1.02,
            CUBE_FACES,
            ident,
            vox.positions,
            batched_colors=colors,
            flat_shading=True,
            opacity=GHOST_OPACITY,
            cast_shadow=False,
            receive_shadow=False,
        )
    else:  # an empty design: nothing to draw but its name
        for name in (
            f"{prefix}/body/voxels",
            f"{prefix}/body/structure",
            f"{prefix}/body/payload",
            f"{prefix}/body/edges",
            f"{prefix}/target/ghost",
        ):
            scene.remove_by_name(name)
    if label:
        scene.add_label(
            f"{prefix}/label", label, position=(0.0, 0.0, r + 0.6), anchor="bottom-center", font_screen_scale=1.1
        )
    else:
        scene.remove_by_name(f"{prefix}/label")
    return SatelliteHandles(body=body, target=target, radius=r)


def side_by_side_positions(radii: list[float]) -> list[tuple[float, float, float]]:
    """Placements along the y axis so that satellites of these radii (module units) never touch."""
    if len(radii) <= 1:
        return [(0.0, 0.0, 0.0)] * len(radii)
    gap = 1.0
    widths = [2 * r for r in radii]
    total = sum(widths) + gap * (len(radii) - 1)
    y, out = -total / 2, []
    for w in widths:
        out.append((0.0, y + w / 2, 0.0))
        y += w + gap
    return out


def lay_out(
    scene, prefixes: list[str], sats: list[SatelliteHandles], *, min_radius: float = 0.0
) -> tuple[float, float, float]:
    """Place the satellites drawn under ``prefixes`` side by side over a floor grid; returns a
    camera position that frames them. ``min_radius`` sizes the floor for tiny (or no) satellites."""
    radii = [s.radius for s in sats]
    places = side_by_side_positions(radii)
    for prefix, pos in zip(prefixes, places):
        scene.add_frame(prefix, show_axes=False, position=pos)
    biggest = max([*radii, min_radius])
    extent = max([abs(p[1]) for p in places] + [0.0]) + biggest
    scene.add_grid(
        "/floor",
        width=2 * extent + 4,
        height=2 * extent + 4,
        cell_size=1.0,
        section_size=5.0,
        position=(0.0, 0.0, -biggest - 0.5),
    )
    return camera_position(extent)


def camera_position(extent: float) -> tuple[float, float, float]:
    """A camera position that frames a scene of half-size ``extent`` around the origin."""
    d = max(6.0, 2.8 * extent)  # the embedded view's canvas can be narrow
    return (0.95 * d, 0.5 * d, 0.55 * d)
