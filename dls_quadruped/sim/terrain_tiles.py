"""The terrain generator's settings and draws: which tile is where, with which parameters.

Layout (IsaacLab style): a grid of square tiles, rows = difficulty (row 0 easiest, along world
x), columns = terrain type (along world y), surrounded by a flat border; the grid is centred on
the world origin. Every tile's outer edge is at z = 0 so neighbouring tiles join without cliffs
(``boxes`` excepted: its cells reach the edge), with a flat platform at its centre where robots
spawn.

Tile types (the name says what a robot meets when it walks *away* from the spawn point):

- ``flat``: z = 0.
- ``rugged``: uniform random heights in [-a, a] on a grid of spacing ``rugged_scale``,
  piecewise linear on MuJoCo's height-field triangulation (edge vertices at 0).
- ``slope_up`` / ``slope_down``: pyramid with gradient s; the centre is a pit (up) or a summit (down).
- ``boxes``: square boxes of side ``box_size`` with random heights in [-h, h] (platform cells at 0).
- ``stairs_up`` / ``stairs_down``: pyramid stairs of step height h and tread ``step_width``;
  the centre platform is at the bottom (up) or at the top (down).

Difficulty parameters (a, s, h) grow linearly from the first to the last row between the
``(easiest, hardest)`` values of the config.

The geometry built from a draw is ``sim/terrain_geometry.py``; the scene and the height lookup,
``sim/terrain.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TERRAIN_TYPES: tuple[str, ...] = ("flat", "rugged", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down")


@dataclass(frozen=True)
class TerrainConfig:
    """Terrain generator settings (lengths in metres; ``(easiest, hardest)`` ranges per row).

    Attributes:
        types: one column per entry, each a name from ``TERRAIN_TYPES`` (repeat to weight a type).
        num_rows: number of difficulty levels.
        tile_size: side of a square tile [m].
        border: width of the flat frame around the tile grid [m].
        platform: side of the flat spawn platform at each tile centre [m].
        rugged_amplitude: half-range a of the uniform noise [m].
        rugged_scale: spacing of the noise samples = the rugged height field's cell [m].
        slope: pyramid gradient s [rise / run].
        box_height: half-range h of the box heights [m].
        box_size: side of one box [m].
        step_height: stair step height [m] (thesis: 5-50 cm).
        step_width: stair tread [m].
        seed: random seed of the generator (rugged, boxes).
    """

    types: tuple[str, ...] = ("flat",)
    num_rows: int = 10
    tile_size: float = 8.0
    border: float = 3.0
    platform: float = 2.0
    rugged_amplitude: tuple[float, float] = (0.01, 0.08)
    rugged_scale: float = 0.2
    slope: tuple[float, float] = (0.0, 0.4)
    box_height: tuple[float, float] = (0.02, 0.15)
    box_size: float = 0.5
    step_height: tuple[float, float] = (0.05, 0.5)
    step_width: float = 0.3
    seed: int = 0

    def __post_init__(self) -> None:
        unknown = [t for t in self.types if t not in TERRAIN_TYPES]
        if unknown or not self.types:
            raise ValueError(f"TerrainConfig.types: unknown or empty {unknown or self.types}; allowed: {TERRAIN_TYPES}")
        if self.num_rows < 1:
            raise ValueError(f"TerrainConfig.num_rows must be >= 1, got {self.num_rows}")
        for name in ("tile_size", "rugged_scale", "box_size", "step_width"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TerrainConfig.{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.platform < self.tile_size:
            raise ValueError(f"TerrainConfig.platform must be in (0, tile_size={self.tile_size}), got {self.platform}")
        for name, size in (("rugged_scale", self.rugged_scale), ("box_size", self.box_size)):
            cells = self.tile_size / size
            if abs(cells - round(cells)) > 1e-6:
                raise ValueError(f"TerrainConfig.tile_size ({self.tile_size}) must be a multiple of {name} ({size})")

    @property
    def is_flat(self) -> bool:
        """True when every column is flat: the scene keeps MuJoCo's ground plane."""
        return all(t == "flat" for t in self.types)

    @property
    def num_steps(self) -> int:
        """Stair steps from the platform to the tile edge."""
        return int(np.floor((0.5 * (self.tile_size - self.platform)) / self.step_width + 1e-9))


def _lerp(rng: tuple[float, float], difficulty: float) -> float:
    return rng[0] + difficulty * (rng[1] - rng[0])


@dataclass
class TileSet:
    """What the generator drew, per tile (R rows x K columns), before any geometry exists.

    Attributes:
        kind: (R, K) int, index into ``TERRAIN_TYPES``.
        param: (R, K) [m or rise/run] the tile's a (rugged), s (slopes), h (stairs); 0 otherwise.
        rugged: (R, K, G, G) [m] rugged vertex heights on the ``rugged_scale`` grid (row = y, col = x).
        boxes: (R, K, n, n) [m] box-cell heights (row = y, col = x).
        centres: (R, K, 2) [m] tile centres, world x, y.
    """

    kind: np.ndarray
    param: np.ndarray
    rugged: np.ndarray
    boxes: np.ndarray
    centres: np.ndarray


def generate_tiles(cfg: TerrainConfig) -> TileSet:
    """Draw every tile's parameters (rugged noise, box heights) from ``cfg.seed``."""
    rng = np.random.default_rng(cfg.seed)
    R, K, L = cfg.num_rows, len(cfg.types), cfg.tile_size
    g = round(L / cfg.rugged_scale) + 1
    nb = round(L / cfg.box_size)
    kind = np.zeros((R, K), dtype=np.int64)
    param = np.zeros((R, K))
    rugged = np.zeros((R, K, g, g))
    boxes = np.zeros((R, K, nb, nb))
    centres = np.zeros((R, K, 2))
    cell_c = (np.arange(nb) + 0.5) * cfg.box_size - 0.5 * L  # box-cell centres, tile frame
    on_platform = np.maximum(np.abs(cell_c)[:, None], np.abs(cell_c)[None, :]) < 0.5 * cfg.platform
    for r in range(R):  # a few dozen tiles, drawn once: a loop is clearer than batching
        difficulty = r / max(R - 1, 1)
        for k, name in enumerate(cfg.types):
            kind[r, k] = TERRAIN_TYPES.index(name)
            centres[r, k] = ((r + 0.5) * L - 0.5 * R * L, (k + 0.5) * L - 0.5 * K * L)
            if name == "rugged":
                a = _lerp(cfg.rugged_amplitude, difficulty)
                param[r, k] = a
                z = rng.uniform(-a, a, size=(g, g))
                z[[0, -1], :] = 0.0  # the tile edge at z = 0
                z[:, [0, -1]] = 0.0
                rugged[r, k] = z
            elif name in ("slope_up", "slope_down"):
                param[r, k] = _lerp(cfg.slope, difficulty)
            elif name == "boxes":
                h = _lerp(cfg.box_height, difficulty)
                param[r, k] = h
                boxes[r, k] = np.where(on_platform, 0.0, rng.uniform(-h, h, size=(nb, nb)))
            elif name in ("stairs_up", "stairs_down"):
                param[r, k] = _lerp(cfg.step_height, difficulty)
    return TileSet(kind, param, rugged, boxes, centres)
