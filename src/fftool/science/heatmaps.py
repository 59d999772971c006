"""Agent-centric rasters for the goal estimator, in batched torch.

A crop is S × S cells of `res` metres around the pedestrian's last observed position c, turned by an
orthonormal matrix R (a rotation, possibly with a mirror): local offset d = Rᵀ (p − c), cell
(col, row) = d / res + ⌊S/2⌋. Cell centres are the integers, so c sits at the centre of cell ⌊S/2⌋ (a
standing pedestrian's goal is one cell, not the corner where four meet). Heat maps are rendered
analytically at the transformed points and the scene map is resampled on the same grid (grid_sample), so
augmentation moves both together.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def rotation(angle: Tensor, mirror: Tensor) -> Tensor:
    """(B, 2, 2) matrices R = rot(angle) · diag(1, ±1)."""
    cos, sin = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([torch.stack([cos, -sin], -1), torch.stack([sin, cos], -1)], -2)
    flip = torch.ones_like(angle) - 2 * mirror.to(angle.dtype)
    return rot * torch.stack([torch.ones_like(flip), flip], -1)[:, None, :]


def world_to_cells(points: Tensor, center: Tensor, R: Tensor, res: float, size: int) -> Tensor:
    """(B, P, 2) world points -> continuous crop cells (col, row)."""
    local = torch.einsum("bji,bpj->bpi", R, points - center[:, None, :])  # Rᵀ (p - c)
    return local / res + size // 2


def cells_to_world(cells: Tensor, center: Tensor, R: Tensor, res: float, size: int) -> Tensor:
    """Inverse of `world_to_cells`: (B, P, 2) cells -> world metres."""
    local = (cells - size // 2) * res
    return torch.einsum("bij,bpj->bpi", R, local) + center[:, None, :]


def render(cells: Tensor, size: int, sigma: float) -> Tensor:
    """(B, P, 2) cell coordinates -> (B, P, S, S) Gaussians with peak 1 (Goal-SAR's heat maps)."""
    grid = torch.arange(size, device=cells.device, dtype=cells.dtype)
    dx = (grid[None, None, None, :] - cells[..., 0, None, None]) ** 2  # (B, P, 1, S)
    dy = (grid[None, None, :, None] - cells[..., 1, None, None]) ** 2  # (B, P, S, 1)
    return torch.exp(-(dx + dy) / (2 * sigma**2))


def render_sum(cells: Tensor, size: int, sigma: float) -> Tensor:
    """(B, P, 2) cell coordinates -> (B, S, S) the sum of their `render` Gaussians, as one batched product of
    each Gaussian's row and column factors: memory B·P·S instead of B·P·S² (P can be a crowd)."""
    grid = torch.arange(size, device=cells.device, dtype=cells.dtype)
    columns = torch.exp(-((grid - cells[..., 0, None]) ** 2) / (2 * sigma**2))  # (B, P, S)
    rows = torch.exp(-((grid - cells[..., 1, None]) ** 2) / (2 * sigma**2))  # (B, P, S)
    return rows.transpose(1, 2) @ columns


def sample_scene(
    maps: Tensor, origins: Tensor, map_res: float, scene: Tensor, center: Tensor, R: Tensor, res: float, size: int
) -> Tensor:
    """Resample the scene rasters on each crop's grid.

    maps: (n_scenes, C, Hm, Wm), cell [i, j] covering world (x0 + j·map_res, y0 + i·map_res).
    origins: (n_scenes, 2) world (x0, y0). scene: (B,) index of each crop's scene. Returns (B, C, S, S);
    cells outside a scene map are zero.
    """
    n, C, Hm, Wm = maps.shape
    cells = torch.arange(size, device=center.device, dtype=center.dtype)
    col, row = torch.meshgrid(cells, cells, indexing="xy")  # (S, S)
    grid_cells = torch.stack([col, row], -1).reshape(1, -1, 2).expand(center.shape[0], -1, -1)
    world = cells_to_world(grid_cells, center, R, res, size)  # (B, S*S, 2)
    map_cells = (world - origins[scene][:, None, :]) / map_res  # continuous (col, row) of the map
    normalised = torch.stack([map_cells[..., 0] / Wm, map_cells[..., 1] / Hm], -1) * 2 - 1
    out = F.grid_sample(
        maps[scene], normalised.reshape(-1, size, size, 2).to(maps.dtype), align_corners=False, padding_mode="zeros"
    )
    return out  # (B, C, S, S)


def softargmax(logits: Tensor) -> Tensor:
    """(B, S, S) logits -> (B, 2) expected (col, row) under the spatial softmax (differentiable)."""
    B, H, W = logits.shape
    p = torch.softmax(logits.reshape(B, -1), dim=-1).reshape(B, H, W)
    rows = torch.arange(H, device=logits.device, dtype=logits.dtype)
    cols = torch.arange(W, device=logits.device, dtype=logits.dtype)
    return torch.stack([(p.sum(1) * cols).sum(-1), (p.sum(2) * rows).sum(-1)], -1)


def sample_goals(
    logits: Tensor,
    k: int,
    *,
    method: str = "ttst",
    temperature: float = 1.0,
    threshold: float = 0.05,
    samples: int = 2000,
    iterations: int = 20,
    mode_radius: int = 0,
    generator: torch.Generator | None = None,
) -> Tensor:
    """(B, S, S) logits -> (B, k, 2) goal cells (col, row); goal 0 is the map's mode.

    The mode is the argmax cell, refined to sub-cell precision by `refine_mode` when mode_radius > 0.
    P = sigmoid(logits / T), cells below threshold · max P dropped. "ttst" (Goal-SAR's test-time
    sampling trick): the remaining k - 1 goals are k-means centres of `samples` draws from P;
    "multinomial": k - 1 plain draws. Draws are jittered uniformly inside their cell, so goals are
    continuous and distinct.
    """
    B, H, W = logits.shape
    flat = logits.reshape(B, -1)
    mode_cells = refine_mode(logits, mode_radius, temperature)[:, None, :]
    if k == 1:
        return mode_cells
    p = torch.sigmoid(flat / temperature)
    p = torch.where(p >= threshold * p.max(-1, keepdim=True).values, p, torch.zeros_like(p))
    n_draws = samples if method == "ttst" else k - 1
    index = torch.multinomial(p, n_draws, replacement=True, generator=generator)  # (B, n)
    jitter = torch.rand(B, n_draws, 2, generator=generator, device=logits.device, dtype=logits.dtype) - 0.5
    draws = torch.stack([index % W, index // W], -1).to(logits.dtype) + jitter
    if method == "ttst":
        draws = _kmeans(draws, k - 1, iterations)
    return torch.cat([mode_cells, draws], 1)


def refine_mode(logits: Tensor, radius: int, temperature: float = 1.0) -> Tensor:
    """(B, S, S) logits -> (B, 2) mode (col, row): the argmax cell, or with radius r > 0 the mean of the cells
    within r of it (a (2r+1)² window) weighted by P = sigmoid(logits / T), Y-net's softargmax made local so a
    second bump elsewhere in the map cannot pull the mode between the two."""
    B, H, W = logits.shape
    best = logits.reshape(B, -1).argmax(-1)
    row, col = best // W, best % W
    if radius == 0:
        return torch.stack([col, row], -1).to(logits.dtype)
    offsets = torch.arange(-radius, radius + 1, device=logits.device)
    rows, cols = row[:, None] + offsets, col[:, None] + offsets  # (B, n)
    inside = ((rows >= 0) & (rows < H))[:, :, None] & ((cols >= 0) & (cols < W))[:, None, :]  # (B, n, n)
    batch = torch.arange(B, device=logits.device)[:, None, None]
    window = logits[batch, rows.clamp(0, H - 1)[:, :, None], cols.clamp(0, W - 1)[:, None, :]]
    weight = torch.sigmoid(window / temperature) * inside
    total = weight.sum((1, 2))
    mean_row = (weight.sum(2) * rows.to(weight.dtype)).sum(1) / total
    mean_col = (weight.sum(1) * cols.to(weight.dtype)).sum(1) / total
    return torch.stack([mean_col, mean_row], -1)


def _kmeans(points: Tensor, k: int, iterations: int) -> Tensor:
    """Batched Lloyd k-means: (B, n, 2) -> (B, k, 2) centres, initialised at evenly spaced draws; stops early
    at a fixed point (centres that no longer move would not move in later iterations either).

    Written in float arithmetic over a (B, k, n) layout, which a CPU vectorises (argmin over the k centres
    and boolean masks do not, and were most of a goal sampling's time): a point belongs to the centre that
    minimises |c|² - 2 c·p (its squared distance less |p|², the same for every centre); exact ties, which
    continuous draws do not produce, would count a point in each tied cluster. Coordinates are centred
    first, so |c|² stays small.
    """
    B, n, _ = points.shape
    offset = points.mean(1, keepdim=True)
    points = points - offset
    start = torch.linspace(0, n - 1, k, device=points.device).round().long()
    centres = points[:, start].clone()
    along_n = points.transpose(1, 2).contiguous()  # (B, 2, n)
    for _ in range(iterations):
        score = torch.baddbmm((centres * centres).sum(-1, keepdim=True), centres, along_n, alpha=-2)  # (B, k, n)
        member = 1 - torch.sign(score - score.amin(1, keepdim=True))  # (B, k, n): 1 at each point's centre
        counts = member.sum(-1)  # (B, k)
        sums = torch.stack([(member * along_n[:, i, None]).sum(-1) for i in range(2)], -1)  # (B, k, 2)
        moved = torch.where(counts[..., None] > 0, sums / counts.clamp_min(1)[..., None], centres)
        if torch.equal(moved, centres):
            break
        centres = moved
    return centres + offset


def constant_velocity_cells(obs_cells: Tensor, pred_len: int) -> Tensor:
    """(B, T, 2) observed cells -> (B, 2): the last step's velocity extrapolated pred_len steps."""
    return obs_cells[:, -1] + pred_len * (obs_cells[:, -1] - obs_cells[:, -2])
