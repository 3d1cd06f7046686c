"""Pictures of meshes (matplotlib, headless): sub-domains, per-vertex values."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np


def partition_colors(partition: np.ndarray, cmap: str = "tab20") -> np.ndarray:
    """(V,) int sub-domain -> (V, 4) RGBA floats, one colour per sub-domain."""
    import matplotlib

    cm = matplotlib.colormaps[cmap]
    k = int(partition.max()) + 1
    return np.asarray([cm(i % cm.N) for i in range(k)])[partition]


def depth_colors(depths: np.ndarray) -> np.ndarray:
    """(V,) per-vertex penetration depth -> (V, 4) RGBA: light grey where 0, red (darker = deeper) where > 0."""
    d = np.asarray(depths, np.float64)
    out = np.tile(np.array([0.78, 0.78, 0.80, 1.0]), (len(d), 1))
    pos = d > 0
    if pos.any():
        t = np.clip(d[pos] / d[pos].max(), 0.0, 1.0)[:, None]
        out[pos] = np.concatenate([0.95 - 0.35 * t, 0.25 - 0.2 * t, 0.2 - 0.15 * t, np.ones_like(t)], 1)
    return out


def render_mesh_png(path: str | Path, vertices: np.ndarray, faces: np.ndarray, vertex_colors: np.ndarray,
                    views: Sequence[tuple[float, float]] = ((15, -90), (15, 0), (15, 90)), title: str = "",
                    size: float = 4.0) -> Path:
    """Render a mesh with per-vertex colours from several views into one PNG.

    Args:
        path: output PNG.
        vertices: (V, 3) float.
        faces: (F, 3) int.
        vertex_colors: (V, 4) RGBA in [0, 1]; a face gets the mean colour of its vertices.
        views: (elevation, azimuth) pairs in degrees, one panel each; the mesh's longest axis is drawn up.
        title: figure title.
        size: inches per panel.

    Returns:
        The path written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    ext = v.max(0) - v.min(0)
    up = int(np.argmax(ext))
    order = [i for i in range(3) if i != up] + [up]
    v = v[:, order]
    face_col = np.asarray(vertex_colors)[f].mean(1)
    # simple shading: darken faces turned away from the viewer's light
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    fig = plt.figure(figsize=(size * len(views) * 0.6, size))
    center = 0.5 * (v.max(0) + v.min(0))
    half = 0.5 * (v.max(0) - v.min(0)).max()
    for i, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), i + 1, projection="3d")
        light = np.array([np.cos(np.radians(azim)), np.sin(np.radians(azim)), 0.6])
        shade = 0.55 + 0.45 * np.abs(n @ (light / np.linalg.norm(light)))
        col = face_col.copy()
        col[:, :3] *= shade[:, None]
        ax.add_collection3d(Poly3DCollection(v[f], facecolors=col, edgecolors="none"))
        ax.set_xlim(center[0] - half, center[0] + half)
        ax.set_ylim(center[1] - half, center[1] + half)
        ax.set_zlim(center[2] - half, center[2] + half)
        ax.view_init(elev=elev, azim=azim)
        ax.set_box_aspect((1, 1, 1), zoom=1.8)
        ax.set_axis_off()
    if title:
        fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80, bbox_inches="tight")
    plt.close(fig)
    return path


def stack_pngs(paths: Sequence[str | Path], out: str | Path) -> Path:
    """One PNG of several stacked top to bottom (padded to the widest), e.g. a mesh before and after."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg

    imgs = [mpimg.imread(p)[..., :3] for p in paths]
    width = max(i.shape[1] for i in imgs)
    rows = [np.pad(i, ((0, 0), (0, width - i.shape[1]), (0, 0)), constant_values=1.0) for i in imgs]
    mpimg.imsave(out, np.clip(np.concatenate(rows, 0), 0.0, 1.0))
    return Path(out)
