"""Draw a ``Recording`` (dashboards.replay) in the paper's four views: road, occupancy grid, safety view, input slice.

Three outputs from the same arrays: an animated GIF (Pillow), an MP4 (imageio + the ffmpeg binary
that the imageio-ffmpeg wheel ships) and a self-contained HTML page (plotly with plotly.js inlined:
play/pause buttons and a frame slider, no network needed). ``write_replay`` picks by suffix.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import plotly.graph_objects as go
import plotly.io as pio
from PIL import Image, ImageDraw, ImageFont

from dashboards.replay import (
    ACTIONS,
    CAR_H,
    CAR_W,
    KIND_AGENT,
    KIND_EGO,
    KIND_TRAFFIC,
    LANE_PX,
    ROW_PX,
    SAFE_LANE_BLOCK,
    SAFE_LANE_FREE,
    SAFE_SPEED_BLOCK,
    SAFE_SPEED_FREE,
    Recording,
)
from sim.config import ConfigError
from sim.layout import N_LANES, N_ROWS

ROAD_W, ROAD_H = N_LANES * LANE_PX, N_ROWS * ROW_PX  # 140 × 700 px, the original canvas
FORMATS = (".gif", ".mp4", ".html")
CA_MAX = 4.0  # largest c·a a grid cell holds (c ≤ 2, a ≤ 2): the top of the occupancy colour scale
OCCUPANCY_SCALE = [[0.0, "rgb(230,80,70)"], [1.0, "rgb(80,230,70)"]]  # slow red → fast green, as in the GIF
SLICE_SCALE = [[0.0, "rgb(40,40,40)"], [1.0, "rgb(255,255,255)"]]  # input 0 (car, off-road) dark → 1 (free) white
OTHER_CAR = 5  # display-only code in the safety view: an occupied cell the rules do not read this frame
VIEW_TITLES = ("road", "occupancy grid", "safety system", "input slice")

CAR_RGB = {KIND_EGO: (220, 40, 40), KIND_AGENT: (255, 150, 40), KIND_TRAFFIC: (225, 225, 225)}
SAFETY_RGB = {
    0: (35, 35, 40),
    SAFE_SPEED_FREE: (90, 200, 120),
    SAFE_SPEED_BLOCK: (230, 60, 60),
    SAFE_LANE_FREE: (80, 170, 230),
    SAFE_LANE_BLOCK: (250, 170, 40),
    OTHER_CAR: (95, 95, 105),
}
# plotly: discrete colour scale for the codes 0–4
SAFETY_LEGEND = (
    (SAFE_SPEED_FREE, "speed rule reads: free"),
    (SAFE_SPEED_BLOCK, "car ahead caps speed"),
    (SAFE_LANE_FREE, "lane change reads: free"),
    (SAFE_LANE_BLOCK, "lane change blocked"),
    (OTHER_CAR, "other car"),
)
N_CODES = len(SAFETY_RGB)
SAFETY_SCALE = [  # discrete: code k takes the band [k, k + 1)/N_CODES
    [edge, "rgb" + str(SAFETY_RGB[code])] for code in range(N_CODES) for edge in (code / N_CODES, (code + 1) / N_CODES)
]


def _occupied(rec: Recording, grid: np.ndarray) -> np.ndarray:
    """Cells holding a car. Not ``grid < free``: the v1 ego is drawn with 10·c·a, usually ≥ 7 (v1 §3.3)."""
    return grid != rec.free


def _grid_rgb(rec: Recording, grid: np.ndarray) -> np.ndarray:
    """(70, 7, 3) colours of the occupancy grid: empty dark, occupied by the occupant's c·a (slow red → fast green)."""
    occ = _occupied(rec, grid).T
    level = np.clip(grid.T / CA_MAX, 0.0, 1.0)  # the v1 ego's 10·c·a saturates
    rgb = np.empty((N_ROWS, N_LANES, 3))
    rgb[...] = (30, 30, 36)
    rgb[occ] = np.stack([230 - 150 * level[occ], 80 + 150 * level[occ], 70 + 0 * level[occ]], axis=-1)
    return rgb.astype(np.uint8)


def _cells_image(rgb: np.ndarray, cell_w: int, cell_h: int) -> Image.Image:
    return Image.fromarray(np.repeat(np.repeat(rgb, cell_h, axis=0), cell_w, axis=1), "RGB")


def _outline(draw: ImageDraw.ImageDraw, box: tuple[float, float, float, float], rgb: tuple[int, int, int]) -> None:
    draw.rectangle(box, outline=rgb, width=2)


def _road(rec: Recording, j: int) -> Image.Image:
    img = Image.new("RGB", (ROAD_W, ROAD_H), (60, 62, 66))
    d = ImageDraw.Draw(img)
    for lane in range(1, N_LANES):
        for y0 in range(0, ROAD_H, 30):
            d.line([(lane * LANE_PX, y0), (lane * LANE_PX, y0 + 15)], fill=(200, 200, 200))
    for i in np.argsort(-rec.kind):  # ego drawn last, on top
        x, y = float(rec.x[j, i]), float(rec.y[j, i])
        d.rectangle((x, y, x + CAR_W, y + CAR_H), fill=CAR_RGB[int(rec.kind[i])], outline=(0, 0, 0))
    return img


def _grid(rec: Recording, j: int) -> Image.Image:
    img = _cells_image(_grid_rgb(rec, rec.grid[j]), LANE_PX, ROW_PX)
    rows, width = rec.inputs.shape[1:]
    l0, r0 = int(rec.slice_lane0[j]), int(rec.slice_row0[j])
    _outline(
        ImageDraw.Draw(img),
        (l0 * LANE_PX, r0 * ROW_PX, (l0 + width) * LANE_PX - 1, (r0 + rows) * ROW_PX - 1),
        (80, 220, 255),
    )
    return img


def _safety_codes(rec: Recording, j: int) -> np.ndarray:
    """(70, 7) the safety view's display codes: the rules' cells, other cars (OTHER_CAR) elsewhere."""
    codes = rec.safety_cells[j].T
    return np.where(_occupied(rec, rec.grid[j]).T & (codes == 0), OTHER_CAR, codes).astype(np.int8)


def _safety(rec: Recording, j: int) -> Image.Image:
    palette = np.array([SAFETY_RGB[c] for c in range(N_CODES)], dtype=np.uint8)
    rgb = palette[_safety_codes(rec, j)]
    img = _cells_image(rgb, LANE_PX, ROW_PX)
    x, y = float(rec.x[j, 0]), float(rec.y[j, 0])
    _outline(ImageDraw.Draw(img), (x, y, x + CAR_W, y + CAR_H), (255, 255, 255))
    return img


def _slice(rec: Recording, j: int) -> Image.Image:
    rows, width = rec.inputs.shape[1:]
    zoom = min(2 * ROAD_W / (width * LANE_PX), ROAD_H / (max(rows, 1) * ROW_PX))  # up to twice a road's width
    cell_w = max(1, int(LANE_PX * zoom))
    cell_h = max(1, int(ROW_PX * zoom))
    level = np.clip(rec.inputs[j], 0.0, 1.0)
    gray = (40 + 215 * level).astype(np.uint8)
    img = _cells_image(np.repeat(gray[:, :, None], 3, axis=2), cell_w, cell_h)
    ahead = rec.config.patches_ahead
    ls = rec.config.lanes_side
    if ahead < rows:  # the ego's own rows are in the slice (patches_behind > 0)
        _outline(
            ImageDraw.Draw(img),
            (ls * cell_w, ahead * cell_h, (ls + 1) * cell_w - 1, min(ahead + 4, rows) * cell_h - 1),
            (220, 40, 40),
        )
    return img


def _caption(rec: Recording, j: int) -> str:
    last = np.flatnonzero((rec.decision_frame <= rec.frame[j]) & (rec.decision_car == 0))
    act = ACTIONS[int(rec.decision_action[last[-1]])] if len(last) else "-"
    return (
        f"{rec.name}  frame {int(rec.frame[j])}/{rec.run_frames}  ego {rec.mph[j, 0]:.1f} mph  "
        f"action {act}  score so far {rec.running_score[j]:.2f} (run {rec.score:.2f})"
    )


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)  # Pillow's bundled FreeType font
    except (TypeError, OSError):  # Pillow built without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def render_frame(rec: Recording, j: int, scale: float = 0.75) -> Image.Image:
    """Kept frame ``j`` as one image: the four views side by side under a one-line caption."""
    panels = [_road(rec, j), _grid(rec, j), _safety(rec, j), _slice(rec, j)]
    gap, top = 16, 62
    width = gap + sum(p.width + gap for p in panels)
    canvas = Image.new("RGB", (width, top + ROAD_H + 2 * gap + 8), (250, 250, 250))
    d = ImageDraw.Draw(canvas)
    font = _font(13)
    d.text((gap, 6), _caption(rec, j), fill=(0, 0, 0), font=font)
    x = gap
    for title, panel in zip(VIEW_TITLES, panels, strict=True):
        d.text((x, top - 18), title, fill=(40, 40, 40), font=font)
        canvas.paste(panel, (x, top))
        x += panel.width + gap
    left = "left ok" if rec.can_left[j] else "left blocked"
    right = "right ok" if rec.can_right[j] else "right blocked"
    d.text((gap, 24), f"ego safety factor c={rec.safety[j, 0]:.2f}, {left}, {right}", fill=(40, 40, 40), font=font)
    x, y = gap, top + ROAD_H + 8
    for code, label in SAFETY_LEGEND:
        d.rectangle((x, y, x + 12, y + 12), fill=SAFETY_RGB[code])
        d.text((x + 16, y - 1), label, fill=(40, 40, 40), font=font)
        x += 30 + int(d.textlength(label, font=font))
    if scale != 1.0:
        canvas = canvas.resize((round(canvas.width * scale), round(canvas.height * scale)), Image.Resampling.BILINEAR)
    return canvas


def frames(rec: Recording, scale: float = 0.75) -> Iterator[Image.Image]:
    """Every kept frame, rendered."""
    for j in range(len(rec)):
        yield render_frame(rec, j, scale)


def write_gif(rec: Recording, path: str | Path, fps: float = 15.0, scale: float = 0.75) -> Path:
    """Animated GIF, looping; one image per kept frame."""
    quantize = Image.Quantize.FASTOCTREE  # the median-cut default costs ~8× more for the same few colours
    images = [im.quantize(colors=64, method=quantize, dither=Image.Dither.NONE) for im in frames(rec, scale)]
    out = Path(path)
    images[0].save(out, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0, optimize=False)
    return out


def write_mp4(rec: Recording, path: str | Path, fps: float = 15.0, scale: float = 0.75) -> Path:
    """H.264 MP4 through imageio-ffmpeg's bundled ffmpeg (frame sizes padded to even numbers)."""
    import imageio.v2 as imageio

    out = Path(path)
    writer: Any = imageio.get_writer(out, fps=fps, codec="libx264", quality=7, macro_block_size=2)
    with writer:
        for im in frames(rec, scale):
            arr = np.asarray(im)
            h, w = arr.shape[0] - arr.shape[0] % 2, arr.shape[1] - arr.shape[1] % 2
            writer.append_data(arr[:h, :w])
    return out


# -- HTML (plotly) ---------------------------------------------------------------------------
# Traces and frames are built as plain dicts: validating 4 × hundreds of frames through
# ``plotly.graph_objects`` costs seconds; ``figure()`` validates once for callers that want objects.


def _car_polygons(rec: Recording, j: int, kind: int) -> tuple[list[float | None], list[float | None]]:
    xs: list[float | None] = []
    ys: list[float | None] = []
    for i in np.flatnonzero(rec.kind == kind):
        x, y = round(float(rec.x[j, i]), 1), round(float(rec.y[j, i]), 1)
        xs += [x, x + CAR_W, x + CAR_W, x, x, None]
        ys += [y, y, y + CAR_H, y + CAR_H, y, None]
    return xs, ys


def _frame_traces(rec: Recording, j: int) -> list[dict[str, Any]]:
    """The traces of kept frame ``j`` (the same traces, in the same order, for every frame)."""
    traces: list[dict[str, Any]] = []
    for kind, label in ((KIND_TRAFFIC, "traffic"), (KIND_AGENT, "agents"), (KIND_EGO, "ego")):
        if not np.any(rec.kind == kind):
            continue
        xs, ys = _car_polygons(rec, j, kind)
        rgb = "rgb" + str(CAR_RGB[kind])
        traces.append(
            {"type": "scatter", "x": xs, "y": ys, "name": label, "mode": "lines", "fill": "toself", "fillcolor": rgb,
             "line": {"color": "black", "width": 1}, "hoverinfo": "name", "xaxis": "x", "yaxis": "y"}
        )  # fmt: skip
    cars = np.flatnonzero(rec.kind >= 0)
    traces.append(
        {"type": "scatter", "x": np.round(rec.x[j] + CAR_W / 2, 1), "y": np.round(rec.y[j] + CAR_H / 2, 1),
         "mode": "markers", "marker": {"size": 1, "opacity": 0}, "name": "cars", "xaxis": "x", "yaxis": "y",
         "text": [f"car {i}: {rec.mph[j, i]:.1f} mph, c={rec.safety[j, i]:.2f}" for i in cars],
         "hoverinfo": "text"}
    )  # fmt: skip
    grid = rec.grid[j].T
    traces.append(
        {"type": "heatmap", "z": np.where(_occupied(rec, grid), np.round(grid, 3), np.nan), "x0": 0.5, "dx": 1,
         "y0": 0.5, "dy": 1, "zmin": 0, "zmax": CA_MAX, "colorscale": OCCUPANCY_SCALE, "showscale": False,
         "name": "occupancy (c·a)", "xaxis": "x2", "yaxis": "y2",
         "hovertemplate": "lane %{x:.0f}, row %{y:.0f}: c·a = %{z}<extra></extra>"}
    )  # fmt: skip
    rows, width = rec.inputs.shape[1:]
    l0, r0 = int(rec.slice_lane0[j]), int(rec.slice_row0[j])
    traces.append(
        {"type": "scatter", "x": [l0, l0 + width, l0 + width, l0, l0], "y": [r0, r0, r0 + rows, r0 + rows, r0],
         "mode": "lines", "line": {"color": "rgb(80,220,255)", "width": 2}, "name": "input slice",
         "xaxis": "x2", "yaxis": "y2"}
    )  # fmt: skip
    traces.append(
        {"type": "heatmap", "z": _safety_codes(rec, j), "x0": 0.5, "dx": 1, "y0": 0.5, "dy": 1, "zmin": -0.5,
         "zmax": N_CODES - 0.5, "colorscale": SAFETY_SCALE, "showscale": False, "name": "safety view",
         "xaxis": "x3", "yaxis": "y3", "hovertemplate": "lane %{x:.0f}, row %{y:.0f}: code %{z}<extra></extra>"}
    )  # fmt: skip
    ex, ey = float(rec.x[j, 0]) / LANE_PX, float(rec.y[j, 0]) / ROW_PX
    cw, ch = CAR_W / LANE_PX, CAR_H / ROW_PX
    traces.append(
        {"type": "scatter", "x": np.round([ex, ex + cw, ex + cw, ex, ex], 3),
         "y": np.round([ey, ey, ey + ch, ey + ch, ey], 3), "mode": "lines",
         "line": {"color": "white", "width": 2}, "name": "ego", "xaxis": "x3", "yaxis": "y3"}
    )  # fmt: skip
    ls, ahead = rec.config.lanes_side, rec.config.patches_ahead
    traces.append(
        {"type": "heatmap", "z": np.round(rec.inputs[j], 3), "x": np.arange(-ls, ls + 1),
         "y": np.arange(-ahead, rows - ahead), "zmin": 0, "zmax": 1, "colorscale": SLICE_SCALE,
         "showscale": False, "name": "input slice", "xaxis": "x4", "yaxis": "y4",
         "hovertemplate": "lane %{x:+d}, row %{y:+d}: %{z}<extra></extra>"}
    )  # fmt: skip
    return traces


def _title(rec: Recording, j: int) -> str:
    left = "ok" if rec.can_left[j] else "blocked"
    right = "ok" if rec.can_right[j] else "blocked"
    return f"{_caption(rec, j)}<br>safety factor c={rec.safety[j, 0]:.2f}, move left {left}, move right {right}"


def _axes(rec: Recording) -> dict[str, Any]:
    """Four side-by-side subplots (road px, grid lanes × rows twice, the slice relative to the ego); y downwards."""
    rows = rec.inputs.shape[1]
    ls, ahead = rec.config.lanes_side, rec.config.patches_ahead
    spans = ((0.0, 0.2), (0.26, 0.46), (0.52, 0.72), (0.78, 1.0))
    ranges = (
        ([0, ROAD_W], [ROAD_H, 0], "x [px]", "y [px]"),
        ([0, N_LANES], [N_ROWS, 0], "lane", "row"),
        ([0, N_LANES], [N_ROWS, 0], "lane", "row"),
        ([-ls - 0.5, ls + 0.5], [rows - ahead - 0.5, -ahead - 0.5], "lane (relative)", "row (relative)"),
    )
    out: dict[str, Any] = {}
    for k, ((x0, x1), (xr, yr, xt, yt)) in enumerate(zip(spans, ranges, strict=True), start=1):
        suffix = "" if k == 1 else str(k)
        out[f"xaxis{suffix}"] = {"domain": [x0, x1], "range": xr, "title": {"text": xt}, "showgrid": False,
                                 "anchor": f"y{suffix}", "zeroline": False}  # fmt: skip
        out[f"yaxis{suffix}"] = {"domain": [0.0, 1.0], "range": yr, "title": {"text": yt}, "showgrid": False,
                                 "anchor": f"x{suffix}", "zeroline": False}  # fmt: skip
    out["annotations"] = [
        {"text": title, "x": (x0 + x1) / 2, "y": 1.0, "xref": "paper", "yref": "paper", "yanchor": "bottom",
         "showarrow": False, "font": {"size": 14}}
        for title, (x0, x1) in zip(VIEW_TITLES, spans, strict=True)
    ]  # fmt: skip
    legend = " &nbsp; ".join(
        f"<span style='color:rgb{SAFETY_RGB[code]}'>■</span> {label}" for code, label in SAFETY_LEGEND
    )
    out["annotations"].append(
        {"text": "safety system: " + legend, "x": 0.5, "y": 1.045, "xref": "paper", "yref": "paper",
         "xanchor": "center", "yanchor": "bottom", "showarrow": False, "font": {"size": 12}}
    )  # fmt: skip
    return out


def figure_dict(rec: Recording, duration_ms: int = 60) -> dict[str, Any]:
    """The replay page's figure as a plain plotly dict: frame 0's traces, one animation frame per kept frame."""
    names = [str(int(f)) for f in rec.frame]
    play = {"frame": {"duration": duration_ms, "redraw": True}, "fromcurrent": True, "transition": {"duration": 0}}
    pause = {"frame": {"duration": 0, "redraw": False}, "mode": "immediate", "transition": {"duration": 0}}
    step = {"mode": "immediate", "frame": {"duration": 0, "redraw": True}, "transition": {"duration": 0}}
    layout = {
        **_axes(rec),
        "title": {"text": _title(rec, 0), "font": {"size": 13}},
        "height": 950,
        "margin": {"t": 135, "b": 150, "l": 60, "r": 30},
        "showlegend": False,
        "plot_bgcolor": "rgb(60,62,66)",
        "updatemenus": [
            {"type": "buttons", "direction": "left", "x": 0.0, "y": -0.09, "xanchor": "left", "yanchor": "top",
             "buttons": [{"label": "▶ play", "method": "animate", "args": [None, play]},
                         {"label": "❚❚ pause", "method": "animate", "args": [[None], pause]}]}
        ],
        "sliders": [
            {"active": 0, "x": 0.16, "y": -0.06, "len": 0.84, "currentvalue": {"prefix": "frame "},
             "steps": [{"label": n, "method": "animate", "args": [[n], step]} for n in names]}
        ],
    }  # fmt: skip
    first = _frame_traces(rec, 0)
    indices = list(range(len(first)))
    frames_ = [
        {
            "name": names[j],
            "data": _frame_traces(rec, j),
            "traces": indices,
            "layout": {"title": {"text": _title(rec, j)}},
        }
        for j in range(len(rec))
    ]
    return {"data": first, "layout": layout, "frames": frames_}


def figure(rec: Recording, duration_ms: int = 60) -> go.Figure:
    """``figure_dict`` as a validated ``plotly.graph_objects.Figure`` (for callers composing figures)."""
    return go.Figure(figure_dict(rec, duration_ms))


def write_html(rec: Recording, path: str | Path) -> Path:
    """Self-contained HTML page (plotly.js inlined, works offline) with the animated four views."""
    out = Path(path)
    html = pio.to_html(figure_dict(rec), full_html=True, include_plotlyjs=True, auto_play=False, validate=False)
    out.write_text(html.replace("<head>", f"<head><title>replay: {rec.name}</title>", 1), encoding="utf-8")
    return out


def write_replay(rec: Recording, path: str | Path, fps: float = 15.0) -> Path:
    """Write ``rec`` as GIF, MP4 or HTML, chosen by the suffix of ``path``."""
    out = Path(path)
    suffix = out.suffix.lower()
    if suffix not in FORMATS:
        raise ConfigError(f"out: '{out}' has no replay format; use a name ending in {', '.join(FORMATS)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        return write_gif(rec, out, fps)
    if suffix == ".mp4":
        return write_mp4(rec, out, fps)
    return write_html(rec, out)


__all__ = [
    "FORMATS",
    "figure",
    "figure_dict",
    "frames",
    "render_frame",
    "write_gif",
    "write_html",
    "write_mp4",
    "write_replay",
]
