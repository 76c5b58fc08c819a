"""The synthetic room: its layout (room bounds, the region cameras stay in) and random scenes of
textured boxes in it (numpy only; rendered by :mod:`.render`).

World frame and units are those of :mod:`.trajectories` (metres, x right, y down, z towards the
far wall). :func:`make_room_scene` keeps its boxes at least ``BOX_CLEARANCE`` away from
``CAMERA_REGION_MIN``/``CAMERA_REGION_MAX``; every trajectory of :mod:`.trajectories` keeps the
camera centre inside that region, so all rendered depths stay above ~0.4 m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Room bounds in world coordinates (metres): 6 m wide (x), 3 m high (y, down), 8 m deep (z).
ROOM_MIN = np.array([-3.0, -1.5, -4.0])
ROOM_MAX = np.array([3.0, 1.5, 4.0])
#: Axis-aligned volume the camera centres of all trajectories stay in (eye height 1.25-1.85 m).
CAMERA_REGION_MIN = np.array([-0.8, -0.35, -2.8])
CAMERA_REGION_MAX = np.array([0.8, 0.25, -1.2])
#: Minimum distance (metres) between any scene box and the camera region.
BOX_CLEARANCE = 0.6

__all__ = [
    "BOX_CLEARANCE",
    "CAMERA_REGION_MAX",
    "CAMERA_REGION_MIN",
    "ROOM_MAX",
    "ROOM_MIN",
    "RoomScene",
    "make_room_scene",
    "surface_distance",
]


@dataclass
class RoomScene:
    """An axis-aligned room (the camera is inside it) containing axis-aligned boxes; world frame and
    units as in :mod:`.trajectories` (metres, y down).

    Surfaces are indexed ``6 * k + 2 * axis + side`` where ``k = 0`` is the room and ``k = 1 + b`` is
    box ``b``; ``side`` is 0 for the face at the minimum of ``axis`` and 1 for the maximum.

    Attributes:
        room_min, room_max: (3,) float64 room bounds.
        box_min, box_max: (B, 3) float64 box bounds.
        surface_seed: (S,) int32 texture seed per surface, S = 6 * (B + 1).
        surface_colours: (S, 3, 3) float32 three RGB colours in [0, 1] per surface (blended by noise,
            colour of the stripes/checks).
        surface_pattern: (S, 4) float32 per surface: kind (0 stripes, 1 checks), period (m),
            orientation (rad), weight in [0, 1].
    """

    room_min: np.ndarray
    room_max: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray
    surface_seed: np.ndarray
    surface_colours: np.ndarray
    surface_pattern: np.ndarray

    @property
    def n_boxes(self) -> int:
        return self.box_min.shape[0]


def _random_colour(rng: np.random.Generator) -> np.ndarray:
    """A random moderately saturated RGB colour in [0, 1] (HSV with s in [0.3, 0.8], v in [0.35, 0.95])."""
    h, s, v = rng.uniform(0.0, 1.0), rng.uniform(0.3, 0.8), rng.uniform(0.35, 0.95)
    k = (np.array([5.0, 3.0, 1.0]) + 6.0 * h) % 6.0
    return v - v * s * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


def _boxes_overlap(a_min, a_max, b_min, b_max, gap: float = 0.0) -> bool:
    return bool(np.all(a_min < b_max + gap) and np.all(b_min < a_max + gap))


def make_room_scene(seed: int = 0, n_boxes: int = 6) -> RoomScene:
    """A random room scene: the room of ``ROOM_MIN``/``ROOM_MAX`` with ``n_boxes``
    non-overlapping boxes of 0.3-1.2 m sides, kept ``BOX_CLEARANCE`` away from the camera region.

    Boxes cycle through three placements: *near* (in front of the camera region, 0.6-2.2 m from it,
    roughly centred in x), *far* (the far half of the room, 2-7 m away) and *side* (beside or
    behind the camera region); about half stand on the floor, the others float. Deterministic given
    ``seed``.
    """
    rng = np.random.default_rng([seed, 0])
    clear_min, clear_max = CAMERA_REGION_MIN - BOX_CLEARANCE, CAMERA_REGION_MAX + BOX_CLEARANCE
    # Per placement: z range of the whole box, and where its x goes ("centre", "any" or "beside" the
    # clear volume).
    front = clear_max[2]
    placements = [
        ((front, front + 1.6), "centre"),
        ((1.0, ROOM_MAX[2]), "any"),
        ((ROOM_MIN[2], front), "beside"),
    ]
    box_min, box_max = [], []
    for b in range(n_boxes):
        (z_lo, z_hi), where = placements[b % 3]
        for _ in range(1000):
            size = rng.uniform(0.3, 1.2, 3)
            lo = rng.uniform(ROOM_MIN, ROOM_MAX - size)
            lo[2] = rng.uniform(z_lo, max(z_lo, z_hi - size[2]))
            if where == "centre":
                lo[0] = rng.uniform(-1.8, 1.8) - size[0] / 2.0
            elif where == "beside":
                left = rng.uniform(ROOM_MIN[0], clear_min[0] - size[0])
                right = rng.uniform(clear_max[0], ROOM_MAX[0] - size[0])
                lo[0] = left if rng.uniform() < 0.5 else right
            if rng.uniform() < 0.5:
                lo[1] = ROOM_MAX[1] - size[1]  # stands on the floor
            hi = lo + size
            inside = np.all(lo >= ROOM_MIN) and np.all(hi <= ROOM_MAX)
            others = zip(box_min, box_max, strict=True)
            if (
                inside
                and not _boxes_overlap(lo, hi, clear_min, clear_max)
                and not any(_boxes_overlap(lo, hi, m, M, gap=0.05) for m, M in others)
            ):
                box_min.append(lo)
                box_max.append(hi)
                break
        else:
            raise RuntimeError(f"could not place box {b} of {n_boxes}; use fewer boxes")

    n_surfaces = 6 * (n_boxes + 1)
    colours = np.stack([np.stack([_random_colour(rng) for _ in range(3)]) for _ in range(n_surfaces)])
    pattern = np.stack(
        [
            rng.integers(0, 2, n_surfaces),  # kind
            rng.uniform(0.12, 0.6, n_surfaces),  # period (m)
            rng.uniform(0.0, np.pi, n_surfaces),  # orientation (rad)
            rng.uniform(0.2, 0.5, n_surfaces),  # weight
        ],
        axis=-1,
    )
    return RoomScene(
        room_min=ROOM_MIN.copy(),
        room_max=ROOM_MAX.copy(),
        box_min=np.array(box_min, dtype=np.float64).reshape(-1, 3),
        box_max=np.array(box_max, dtype=np.float64).reshape(-1, 3),
        surface_seed=rng.integers(0, 2**30, n_surfaces).astype(np.int32),
        surface_colours=colours.astype(np.float32),
        surface_pattern=pattern.astype(np.float32),
    )


def surface_distance(scene: RoomScene, points: np.ndarray) -> np.ndarray:
    """Distance (metres) from world points (..., 3) to the nearest surface of the scene (room planes or
    box faces); float64 numpy reference, independent of the renderer."""
    p = np.asarray(points, dtype=np.float64)[..., None, :]  # (..., 1, 3)
    d = np.min(np.abs(np.concatenate([p - scene.room_min, p - scene.room_max], -2)), axis=(-2, -1))
    for lo, hi in zip(scene.box_min, scene.box_max, strict=True):
        q = np.maximum(lo - p[..., 0, :], p[..., 0, :] - hi)  # > 0 outside along an axis
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        inside = -np.minimum(np.max(q, axis=-1), 0.0)
        d = np.minimum(d, outside + inside)
    return d
