"""World-aligned semantic maps of each scene, built from its image and homography only.

Reads: `scenes/<scene>/reference.png`, `world_to_pixel.txt` and (eth, hotel) `obstacle_map.png`.
Writes: `maps/<fp>/<scene>.npy` (C, H, W), transforms.json, and `<scene>_check.png` for people to check.
Run: `fftool maps`. With `data.dataset`, the one scene is the dataset's: its `scene_image` and `homography`
(image pixel -> world metres, inverted here), or none (its crops get the all-zero map, as uni_examples').

The raster covers the ground footprint of the image (its corners through the inverse homography) plus
a margin, so no trajectory is used to build any map, and a test scene's map never sees its test data.
Channels: 0 = inside the image footprint, 1 = obstacle (where an obstacle map exists), 2.. = one-hot
colour clusters (k-means in CIE Lab, OpenCV), ordered by mean lightness so channel meaning is
comparable across scenes.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np

from fftool.artifacts.hashing import sha256_file
from fftool.artifacts.schema import COMMANDS, MAPS_TRANSFORMS_FILE, VERSIONS, map_check_file, map_file
from fftool.artifacts.store import Artifact
from fftool.config import MapsConfig, PipelineConfig
from fftool.dataset.custom import load_dataset
from fftool.dataset.scene_images import SceneImage, apply_homography, read_homography, read_image, read_scene
from fftool.dataset.scenes import SCENES
from fftool.outputs import replacing_file
from fftool.stages.contract import Reads, Stage, StageContext

NAME: Final = "maps"
_FILES = ("reference.png", "world_to_pixel.txt", "obstacle_map.png")


def scene_input_hashes(scenes_dir: Path) -> dict[str, str]:
    """Content hashes of every scene file present (missing scenes fall back to no map)."""
    return {
        f"scenes/{scene}/{name}": sha256_file(scenes_dir / scene / name)
        for scene in SCENES
        for name in _FILES
        if (scenes_dir / scene / name).is_file()
    }


def channel_names(cfg: MapsConfig) -> list[str]:
    return ["inside", "obstacle", *(f"colour{k}" for k in range(cfg.colour_clusters))]


def build_scene(
    scene_dir: Path, cfg: MapsConfig
) -> tuple[np.ndarray, dict[str, Any], tuple[np.ndarray, np.ndarray]] | None:
    """(C, H, W) raster, its transform, and the check figure's RGB images (the reference, and its warp onto
    the raster's grid); None for a scene without geometry."""
    scene = read_scene(scene_dir)
    if scene is None:
        return None
    return build_from_image(scene, scene_dir / "obstacle_map.png", cfg)


def build_from_image(
    scene: SceneImage, obstacle_map: Path | None, cfg: MapsConfig
) -> tuple[np.ndarray, dict[str, Any], tuple[np.ndarray, np.ndarray]]:
    """`build_scene` from an image and its world->pixel homography (and an obstacle map where one exists)."""
    world_to_pixel, image = scene.homography, scene.image
    h, w = image.shape[:2]
    corners = apply_homography(np.linalg.inv(world_to_pixel), np.array([[0, 0], [w, 0], [0, h], [w, h]], float))
    res = cfg.resolution_m
    low = corners.min(0) - cfg.margin_m
    width, height = (np.ceil((corners.max(0) + cfg.margin_m - low) / res)).astype(int)
    # destination cell (col j, row i) -> its world centre -> image pixel
    cell_to_world = np.array([[res, 0, low[0] + res / 2], [0, res, low[1] + res / 2], [0, 0, 1]])
    cell_to_pixel = world_to_pixel @ cell_to_world
    flags = cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(image, cell_to_pixel, (width, height), flags=flags | cv2.INTER_LINEAR)
    inside = cv2.warpPerspective(
        np.full((h, w), 255, np.uint8), cell_to_pixel, (width, height), flags=flags | cv2.INTER_NEAREST
    )
    inside = inside > 127
    obstacle = np.zeros((height, width), np.float32)
    if obstacle_map is not None and obstacle_map.is_file():
        gray = read_image(obstacle_map, cv2.IMREAD_GRAYSCALE)
        obstacle = cv2.warpPerspective(gray, cell_to_pixel, (width, height), flags=flags | cv2.INTER_NEAREST) > 127
        obstacle = obstacle.astype(np.float32)

    lab = cv2.cvtColor(warped, cv2.COLOR_RGB2LAB).reshape(-1, 3).astype(np.float32)
    pixels = lab[inside.reshape(-1)]
    cv2.setRNGSeed(cfg.seed)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.1)
    _, labels, centres = cv2.kmeans(pixels, cfg.colour_clusters, None, criteria, 3, cv2.KMEANS_PP_CENTERS)
    rank = np.argsort(np.argsort(centres[:, 0]))  # lightness order: channel 2 is the darkest cluster
    colour = np.zeros((cfg.colour_clusters, height * width), np.float32)
    colour[rank[labels[:, 0]], np.flatnonzero(inside.reshape(-1))] = 1.0
    raster = np.concatenate(
        [inside[None].astype(np.float32), obstacle[None], colour.reshape(-1, height, width)], axis=0
    )
    transform = {
        "origin_x_m": float(low[0]),
        "origin_y_m": float(low[1]),
        "resolution_m": res,
        "width": int(width),
        "height": int(height),
    }
    return raster, transform, (image, warped)


def _check_figure(
    scene: str, raster: np.ndarray, images: tuple[np.ndarray, np.ndarray], transform: dict, out: Path
) -> None:
    """reference image | warped onto the ground grid | semantic channels with their key, side by side."""
    import matplotlib.pyplot as plt

    fig = _check_figure_drawn(scene, raster, images, transform)
    try:
        with replacing_file(out) as partial:
            fig.savefig(partial, format="png")
    finally:
        plt.close(fig)


def _check_figure_drawn(scene: str, raster: np.ndarray, images: tuple[np.ndarray, np.ndarray], transform: dict) -> Any:
    """The check figure (a matplotlib Figure): the channel panel has a key with one entry per channel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.legend_handler import HandlerTuple

    extent = (
        transform["origin_x_m"],
        transform["origin_x_m"] + transform["width"] * transform["resolution_m"],
        transform["origin_y_m"],
        transform["origin_y_m"] + transform["height"] * transform["resolution_m"],
    )
    reference, warped = images
    colours = _cluster_colours(len(raster) - 2)
    labels = np.where(raster[0] > 0, raster[2:].argmax(0) + 1, 0)  # 0 outside the footprint, c + 1 cluster c
    fig, axes = plt.subplots(1, 3, figsize=(20, 5.4), dpi=90)
    axes[0].imshow(reference)
    axes[0].set_title(f"{scene}: reference image (pixels)")
    axes[1].imshow(warped, origin="lower", extent=extent)
    axes[1].set_title("warped onto the ground plane (metres, y up)")
    cmap = ListedColormap([_OUTSIDE, *colours])
    axes[2].imshow(labels, origin="lower", extent=extent, cmap=cmap, vmin=-0.5, vmax=len(colours) + 0.5)
    if raster[1].any():
        axes[2].contour(raster[1], levels=[0.5], colors="black", origin="lower", extent=extent, linewidths=1.0)
    axes[2].set_title("map channels (key on the right)")
    for ax in axes[1:]:
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    handles, texts = zip(*_channel_key(raster, warped, colours), strict=True)
    axes[2].legend(
        handles,
        texts,
        handler_map={tuple: HandlerTuple(ndivide=None, pad=0.2)},
        loc="upper left",
        bbox_to_anchor=(1.02, 1.0),
        fontsize=9,
        title="channel: meaning (clusters: drawn colour | mean image colour)",
        title_fontsize=9,
        alignment="left",
        handlelength=3.2,
        labelspacing=0.8,
    )
    fig.tight_layout()
    return fig


_OUTSIDE = "#f0f0f0"  # cells outside the image footprint (channel 0 = 0)


def _cluster_colours(n: int) -> list[str]:
    """Distinct colours to draw colour clusters 0..n-1 in (never black: black outlines obstacles)."""
    import matplotlib

    palette = matplotlib.colormaps["tab10" if n <= 7 else "tab20"]
    picks = [i for i in range(palette.N) if i not in (7, 14, 15)][:n]  # skip the greys
    picks += list(range(len(picks), n))  # more clusters than colours: repeat (rarely configured)
    return [matplotlib.colors.to_hex(palette(i % palette.N)) for i in picks]


def _channel_key(raster: np.ndarray, warped: np.ndarray, colours: list[str]) -> list[tuple[Any, str]]:
    """(legend handle, label), one per channel. A colour cluster's handle is two swatches: the colour it is
    drawn in, then its mean image colour (its cells' pixels averaged), so a reader can tell which surface it is."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    inside = raster[0] > 0
    footprint = max(int(inside.sum()), 1)
    key: list[tuple[Any, str]] = [
        (Patch(facecolor=_OUTSIDE, edgecolor="0.3"), "0 inside: the image footprint (light grey: outside it)"),
    ]
    obstacle = "1 obstacle: black outline" if raster[1].any() else "1 obstacle: none in this scene"
    key.append((Line2D([], [], color="black", lw=1.0), obstacle))
    clusters = len(raster) - 2
    for c in range(clusters):
        cells = raster[2 + c] > 0
        mean = warped[cells].reshape(-1, 3).mean(0) / 255 if cells.any() else np.ones(3)
        order = " (darkest)" if c == 0 else " (lightest)" if c == clusters - 1 and clusters > 1 else ""
        rgb = ", ".join(str(round(v * 255)) for v in mean)
        share = 100 * cells.sum() / footprint
        label = f"{2 + c} colour{c}{order}: {share:.0f}% of footprint, mean RGB ({rgb})"
        swatches = (Patch(facecolor=colours[c], edgecolor="0.3"), Patch(facecolor=tuple(mean), edgecolor="0.3"))
        key.append((swatches, label))
    return key


def rasterise(cfg: MapsConfig, scenes_dir: Path, out_dir: Path) -> dict[str, Any]:
    """One raster per scene with geometry; transforms.json; check PNGs. Returns the manifest stats.

    Args:
        cfg: the `maps` section of the configuration.
        scenes_dir: folder with one sub-folder per scene.
        out_dir: the artifact's build folder.
    """
    transforms, missing = {}, []
    for scene in SCENES:
        built = build_scene(scenes_dir / scene, cfg)
        if built is None:
            missing.append(scene)
            continue
        transforms[scene] = _save_scene(scene, built, out_dir)
    warnings = [f"scene {s}: no reference.png + world_to_pixel.txt; its crops have no map" for s in missing]
    return _finish(cfg, transforms, missing, warnings, out_dir)


def _save_scene(
    name: str, built: tuple[np.ndarray, dict[str, Any], tuple[np.ndarray, np.ndarray]], out_dir: Path
) -> dict[str, Any]:
    """Write one scene's raster and check figure; its transform, for transforms.json."""
    raster, transform, images = built
    np.save(out_dir / map_file(name), raster)
    _check_figure(name, raster, images, transform, out_dir / map_check_file(name))
    return transform


def _finish(
    cfg: MapsConfig, transforms: dict[str, Any], missing: list[str], warnings: list[str], out_dir: Path
) -> dict[str, Any]:
    """transforms.json and the manifest stats, for the ETH/UCY scenes and a dataset's scene alike."""
    (out_dir / MAPS_TRANSFORMS_FILE).write_text(
        json.dumps({"scenes": transforms, "channels": channel_names(cfg)}, indent=2)
    )
    return {"scenes": transforms, "channels": channel_names(cfg), "without_geometry": missing, "warnings": warnings}


def rasterise_dataset(cfg: MapsConfig, dataset_toml: Path, out_dir: Path) -> dict[str, Any]:
    """A dataset's one scene: its image and pixel->world homography, or no map (a warning) without them."""
    dataset = load_dataset(dataset_toml)
    transforms, missing = {}, []
    found = dataset.scene_files()
    if found is None:
        missing.append(dataset.name)
    else:
        image_path, homography_path = found
        pixel_to_world = read_homography(homography_path)
        image = cv2.cvtColor(read_image(image_path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        built = build_from_image(SceneImage(image, np.linalg.inv(pixel_to_world)), None, cfg)
        transforms[dataset.name] = _save_scene(dataset.name, built, out_dir)
    warnings = [
        f"dataset {s}: no scene_image + homography; goal crops get an all-zero map (goal variants still run)"
        for s in missing
    ]
    return _finish(cfg, transforms, missing, warnings, out_dir)


def build(cfg: PipelineConfig, inputs: Mapping[str, Artifact], ctx: StageContext) -> dict[str, Any]:
    """The stage contract: one raster per scene of `data.scenes_dir` (or the scene of `data.dataset`)."""
    if cfg.data.dataset:
        return rasterise_dataset(cfg.maps, Path(cfg.data.dataset), ctx.dir)
    return rasterise(cfg.maps, Path(cfg.data.scenes_dir), ctx.dir)


def declare(cfg: PipelineConfig) -> Reads:
    """The raster settings and the scene images and homographies by content (a dataset's, or ETH/UCY's)."""
    data = cfg.data

    def scenes() -> dict[str, str]:
        return load_dataset(data.dataset).scene_hashes() if data.dataset else scene_input_hashes(Path(data.scenes_dir))

    return Reads(params=("maps.*",), raw_files=scenes, locations=("data.scenes_dir", "data.dataset"))


STAGE = Stage(
    NAME,
    VERSIONS[NAME],
    COMMANDS[NAME],
    label="scene maps",
    declare=declare,
    build=build,
    section="maps",
)
