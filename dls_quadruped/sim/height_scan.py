"""Height scanner: a yaw-aligned grid of terrain heights around the base (thesis Table 2).

The terrain is known, so instead of casting rays the scan reads ``Terrain.height_at`` (exact for
MuJoCo's triangulated height field, see ``terrain.py``). Grid: 17 points along the base-yaw x axis
(1.6 m) by 11 along y (1.0 m), 0.1 m apart, centred on the base. Flattened order: x varies fastest,
index = iy * 17 + ix, with ix = 0 at the rear (x = -0.8 m) and iy = 0 on the right (y = -0.5 m).
Value = base z - terrain z - offset (0.5 m), clipped to [-clip, clip].
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from dls_quadruped.core.rotations import yaw_from_quat
from dls_quadruped.sim.terrain import Terrain


@dataclass(frozen=True)
class HeightScanConfig:
    """Scan grid settings: ``size`` (length x, width y) [m], ``resolution`` [m], ``offset`` [m], ``clip`` [m]."""

    size: tuple[float, float] = (1.6, 1.0)
    resolution: float = 0.1
    offset: float = 0.5
    clip: float = 1.0

    @property
    def shape(self) -> tuple[int, int]:
        """(nx, ny) points: (17, 11) by default."""
        return (round(self.size[0] / self.resolution) + 1, round(self.size[1] / self.resolution) + 1)

    @property
    def num_points(self) -> int:
        nx, ny = self.shape
        return nx * ny


def scan_pattern(cfg: HeightScanConfig, device: torch.device | str = "cpu") -> torch.Tensor:
    """Scan points in the yaw frame, (P, 2) [m], x fastest."""
    nx, ny = cfg.shape
    xs = torch.linspace(-0.5 * cfg.size[0], 0.5 * cfg.size[0], nx, device=device)
    ys = torch.linspace(-0.5 * cfg.size[1], 0.5 * cfg.size[1], ny, device=device)
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")  # (ny, nx): row = y, x fastest when flattened
    return torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=-1)


def scan_points_w(pattern: torch.Tensor, base_pos_w: torch.Tensor, base_quat_w: torch.Tensor) -> torch.Tensor:
    """World (x, y) of the scan points, (B, P, 2) [m], from the yaw-frame ``pattern`` (P, 2)."""
    yaw = yaw_from_quat(base_quat_w)
    cos, sin = torch.cos(yaw)[:, None], torch.sin(yaw)[:, None]
    px, py = pattern[:, 0][None], pattern[:, 1][None]
    x = base_pos_w[:, 0:1] + cos * px - sin * py  # rotation by yaw about z
    y = base_pos_w[:, 1:2] + sin * px + cos * py
    return torch.stack([x, y], dim=-1)


def height_scan(terrain: Terrain, pattern: torch.Tensor, base_pos_w: torch.Tensor, base_quat_w: torch.Tensor,
                cfg: HeightScanConfig) -> torch.Tensor:
    """The height-scan observation, (B, P): clip(base z - terrain z - offset, -clip, clip) [m]."""
    xy = scan_points_w(pattern, base_pos_w, base_quat_w)
    z = terrain.height_at(xy[..., 0], xy[..., 1])
    return (base_pos_w[:, 2:3] - z - cfg.offset).clamp(-cfg.clip, cfg.clip)
