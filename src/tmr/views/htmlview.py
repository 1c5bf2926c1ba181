"""One self-contained HTML file to scrub through a :class:`tmr.views.motion.Motion` (plotly, offline).

A top view like the GIF (:mod:`tmr.views.animate`): obstacles, obstacles grown by the safety radius, room, anchor /
goal /
task points, and per frame the tethers (hover: sag [m] and lowest height above the floor [m], Caruso 2021 eq. 22),
cables and links, the bodies as discs of their radius and the leader's trail; tethers are shaded by their sag (colour
bar, the GIF's colours). A time slider and play / pause
buttons move through the frames; the whole plotly.js library is embedded (``include_plotlyjs=True``) so the file
opens without a network. Equal aspect (1 m is as long on x as on y).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from tmr.views.motion import Motion

__all__ = ["build_figure", "write_html"]

_ROLE_COLOR = {
    "robot": "#1f77b4",
    "leader": "#ff7f0e",
    "base": "#7f7f7f",
    "platform": "#d62728",
    "agent": "#9467bd",
    "end_effector": "#dc143c",
}
_LINE_COLOR = {"tether": "#5b2c83", "cable": "#d62728", "link": "#2ca02c"}
_TRAIL = "#17a589"


def _ring_xy(poly: Any) -> tuple[list[float | None], list[float | None]]:
    xs: list[float | None] = []
    ys: list[float | None] = []
    for ring in [poly.exterior, *poly.interiors]:
        c = np.asarray(ring.coords)
        xs += c[:, 0].tolist() + [None]
        ys += c[:, 1].tolist() + [None]
    return xs, ys


def _disc(x: float, y: float, r: float, n: int = 32) -> tuple[list[float], list[float]]:
    a = np.linspace(0.0, 2.0 * np.pi, n + 1)
    return (x + r * np.cos(a)).tolist(), (y + r * np.sin(a)).tolist()


def _moving(motion: Motion, k: int, shown: np.ndarray | None = None) -> list[dict[str, Any]]:
    """Data of the moving traces at sample ``k`` (same order as the traces made by :func:`build_figure`); the trail
    goes through the ``shown`` samples up to ``k`` (every sample if None), so the file grows with the frames, not
    with the samples squared."""
    out: list[dict[str, Any]] = []
    for ln in motion.lines:
        p = ln.points[k]
        text = None
        if ln.sag is not None:
            text = f"{ln.name}: sag {ln.sag[k]:.3f} m, lowest {p[:, 2].min():.3f} m above the floor"
        else:
            text = f"{ln.name}"
        d = {"x": p[:, 0].tolist(), "y": p[:, 1].tolist(), "text": [text] * len(p)}
        if ln.sag is not None:  # shaded by sag, as in the GIF (colour bar: _sag_scale)
            d["line"] = {"color": _sag_color(float(ln.sag[k]), _sag_max(motion)), "width": 3}
        out.append(d)
    if motion.trail is not None:
        tr = motion.track(motion.trail)
        upto = np.arange(k + 1) if shown is None else np.append(shown[shown < k], k)
        out.append({"x": tr.xyz[upto, 0].tolist(), "y": tr.xyz[upto, 1].tolist()})
    for tr in motion.tracks:
        x, y, z = (float(v) for v in tr.xyz[k])
        label = f"{tr.name}: ({x:.3f}, {y:.3f}, {z:.3f}) m"
        if tr.radius > 0:
            xs, ys = _disc(x, y, tr.radius)
            out.append({"x": xs, "y": ys, "text": [label] * len(xs)})
        else:
            out.append({"x": [x], "y": [y], "text": [label]})
    if _has_side(motion):  # the side view (x–z): lines, trail, bodies
        for ln in motion.lines:
            p = ln.points[k]
            out.append({"x": p[:, 0].tolist(), "y": p[:, 2].tolist()})
        if motion.trail is not None:
            tr = motion.track(motion.trail)
            upto = np.arange(k + 1) if shown is None else np.append(shown[shown < k], k)
            out.append({"x": tr.xyz[upto, 0].tolist(), "y": tr.xyz[upto, 2].tolist()})
        for tr in motion.tracks:
            out.append({"x": [float(tr.xyz[k, 0])], "y": [float(tr.xyz[k, 2])]})
    return out


#: Colour scale of the tether sag: matplotlib's plasma_r from 25 % on (the GIF's), light = slack.
_SAG_SCALE = "Plasma_r"


def _sag_max(motion: Motion) -> float:
    return max([float(np.max(ln.sag)) for ln in motion.lines if ln.sag is not None] + [1e-3])


def _sag_color(sag: float, smax: float) -> str:
    from plotly.colors import sample_colorscale

    return str(sample_colorscale(_SAG_SCALE, [0.25 + 0.75 * min(max(sag / smax, 0.0), 1.0)])[0])


def _has_side(motion: Motion) -> bool:
    """MoPICK and CCMA move in height too: they get a side view (x–z) under the top view."""
    return motion.system in ("mcdpr", "ccma")


def _stamp(motion: Motion, k: int) -> str:
    return f"t = {motion.t[k]:.2f} s" if motion.timed else f"sample {k + 1}"


def build_figure(motion: Motion, max_frames: int = 200) -> Any:
    """The plotly figure (static traces, one frame per shown sample, slider and play buttons)."""
    import plotly.graph_objects as go

    from tmr.views.animate import frame_indices

    fig = go.Figure()
    for i, poly in enumerate(motion.obstacles):
        xs, ys = _ring_xy(poly)
        fig.add_trace(
            go.Scatter(
                x=xs,
                y=ys,
                fill="toself",
                mode="lines",
                fillcolor="#9e9e9e",
                line={"color": "#424242", "width": 1},
                name="obstacle",
                legendgroup="obstacle",
                showlegend=i == 0,
                hoverinfo="skip",
            )
        )
    from tmr.views.motion import _polygons

    low_polys = [(low, poly) for low in motion.low_obstacles for poly in _polygons(low.footprint)]
    for i, (low, poly) in enumerate(low_polys):  # a tether may pass over them: lighter, hatched, with the height
        xs, ys = _ring_xy(poly)
        fig.add_trace(
            go.Scatter(
                x=xs,
                y=ys,
                fill="toself",
                mode="lines",
                fillcolor="#e0d5b8",
                fillpattern={"shape": "/", "fgcolor": "#8d6e63"},
                line={"color": "#8d6e63", "width": 1},
                name="low obstacle",
                legendgroup="low obstacle",
                showlegend=i == 0,
                text=f"{low.name}: {low.height:.2f} m",
                hoverinfo="text",
            )
        )
    for i, poly in enumerate(motion.inflated_in_room()):
        xs, ys = _ring_xy(poly)
        fig.add_trace(
            go.Scatter(
                x=xs,
                y=ys,
                mode="lines",
                line={"color": "#555555", "width": 1, "dash": "dash"},
                name="grown by robot radius",
                legendgroup="inflated",
                showlegend=i == 0,
                hoverinfo="skip",
            )
        )
    if motion.system != "ccma":
        x0, y0, x1, y1 = motion.bounds
        fig.add_trace(
            go.Scatter(
                x=[x0, x1, x1, x0, x0],
                y=[y0, y0, y1, y1, y0],
                mode="lines",
                line={"color": "black", "width": 2},
                name="room",
                hoverinfo="skip",
            )
        )
    for name, p in motion.points.items():
        symbol = {"anchor": "square", "goal": "star"}.get(name, "x")
        fig.add_trace(
            go.Scatter(
                x=[p[0]],
                y=[p[1]],
                mode="markers+text",
                text=[name],
                textposition="top right",
                marker={
                    "symbol": symbol,
                    "size": 14 if name == "goal" else 10,
                    "color": "#ff7f0e" if name == "goal" else "black",
                },
                name=name,
                hovertemplate=f"{name}: (%{{x:.3f}}, %{{y:.3f}}) m<extra></extra>",
            )
        )
    if any(ln.sag is not None for ln in motion.lines):  # colour bar of the tether sag (an empty marker trace)
        smax = _sag_max(motion)
        fig.add_trace(
            go.Scatter(
                x=[None],
                y=[None],
                mode="markers",
                showlegend=False,
                hoverinfo="skip",
                marker={
                    "colorscale": [[v, _sag_color(v * smax, smax)] for v in np.linspace(0.0, 1.0, 11)],
                    "cmin": 0.0,
                    "cmax": smax,
                    "color": [0.0],
                    "showscale": True,
                    "colorbar": {"title": {"text": "tether sag [m]"}, "thickness": 14, "len": 0.6},
                },
            )
        )
    n_static = len(fig.data)
    first = _moving(motion, 0)
    j = 0
    seen: set[str] = set()
    for ln in motion.lines:
        d = first[j]
        j += 1
        fig.add_trace(
            go.Scatter(
                x=d["x"],
                y=d["y"],
                text=d["text"],
                mode="lines",
                hoverinfo="text",
                line=d.get("line", {"color": _LINE_COLOR.get(ln.kind, "#2ca02c"), "width": 2}),
                name=ln.kind,
                legendgroup=ln.kind,
                showlegend=ln.kind not in seen,
            )
        )
        seen.add(ln.kind)
    if motion.trail is not None:
        d = first[j]
        j += 1
        tr = motion.track(motion.trail)
        fig.add_trace(
            go.Scatter(
                x=d["x"],
                y=d["y"],
                mode="lines",
                line={"color": _TRAIL, "width": 2},
                name=f"{'leader' if tr.role == 'leader' else tr.name} trail",
                hoverinfo="skip",
            )
        )
    for tr in motion.tracks:
        d = first[j]
        j += 1
        color = _ROLE_COLOR.get(tr.role, "#1f77b4")
        r_txt = f" (r = {tr.radius:g} m)" if tr.radius > 0 else ""
        if tr.radius > 0:
            trace = go.Scatter(
                x=d["x"],
                y=d["y"],
                text=d["text"],
                mode="lines",
                fill="toself",
                hoverinfo="text",
                opacity=0.6,
                line={"color": color, "width": 1.5},
                name=f"{tr.role}{r_txt}",
                legendgroup=tr.role,
                showlegend=tr.role not in seen,
            )
        else:
            trace = go.Scatter(
                x=d["x"],
                y=d["y"],
                text=d["text"],
                mode="markers",
                hoverinfo="text",
                marker={"color": color, "size": 9},
                name=tr.role,
                legendgroup=tr.role,
                showlegend=tr.role not in seen,
            )
        seen.add(tr.role)
        fig.add_trace(trace)
    if _has_side(motion):
        side = {"xaxis": "x2", "yaxis": "y2", "showlegend": False, "hoverinfo": "skip"}
        for ln in motion.lines:
            d = first[j]
            j += 1
            fig.add_trace(
                go.Scatter(
                    x=d["x"], y=d["y"], mode="lines", line={"color": _LINE_COLOR.get(ln.kind, "#2ca02c")}, **side
                )
            )
        if motion.trail is not None:
            d = first[j]
            j += 1
            fig.add_trace(go.Scatter(x=d["x"], y=d["y"], mode="lines", line={"color": _TRAIL, "width": 2}, **side))
        for tr in motion.tracks:
            d = first[j]
            j += 1
            color = _ROLE_COLOR.get(tr.role, "#1f77b4")
            fig.add_trace(go.Scatter(x=d["x"], y=d["y"], mode="markers", marker={"color": color, "size": 8}, **side))
    moving_ids = list(range(n_static, len(fig.data)))
    idx = frame_indices(motion, fps=10.0, max_frames=max_frames)
    frames = []
    for k in idx:
        data = [go.Scatter(**d) for d in _moving(motion, int(k), idx)]
        frames.append(
            go.Frame(data=data, traces=moving_ids, name=str(int(k)), layout={"title": {"text": _title(motion, int(k))}})
        )
    fig.frames = frames
    step_ms = 100
    slider = {
        "active": 0,
        "currentvalue": {"prefix": "", "visible": True},
        "pad": {"t": 40},
        "x": 0.2,
        "len": 0.8,
        "font": {"size": 9},
        "steps": [
            {
                "label": f"{motion.t[k]:.2f}" if motion.timed else str(int(k) + 1),
                "method": "animate",
                "args": [
                    [str(int(k))],
                    {"mode": "immediate", "frame": {"duration": 0, "redraw": True}, "transition": {"duration": 0}},
                ],
            }
            for k in idx
        ],
    }
    slider["currentvalue"]["prefix"] = "t [s] = " if motion.timed else "sample "
    buttons = [
        {
            "label": "▶ play",
            "method": "animate",
            "args": [
                None,
                {"frame": {"duration": step_ms, "redraw": True}, "fromcurrent": True, "transition": {"duration": 0}},
            ],
        },
        {
            "label": "❚❚ pause",
            "method": "animate",
            "args": [
                [None],
                {"mode": "immediate", "frame": {"duration": 0, "redraw": False}, "transition": {"duration": 0}},
            ],
        },
    ]
    ex0, ey0, ex1, ey1 = motion.extent(pad=0.3)
    if _has_side(motion):
        zall = np.concatenate(
            [np.asarray(tr.xyz)[:, 2] for tr in motion.tracks]
            + [np.asarray(ln.points)[..., 2].ravel() for ln in motion.lines]
        )
        fig.update_layout(
            xaxis2={"title": "x [m]", "range": [ex0, ex1], "matches": "x", "anchor": "y2", "constrain": "domain"},
            yaxis2={
                "title": "z [m] (side view)",
                "range": [min(0.0, float(zall.min())) - 0.1, float(zall.max()) + 0.15],
                "domain": [0.0, 0.22],
                "anchor": "x2",
                "scaleanchor": "x2",
                "scaleratio": 1,
                "constrain": "domain",
            },
        )
    fig.update_layout(
        title={"text": _title(motion, 0)},
        xaxis={"title": "x [m]", "range": [ex0, ex1], "constrain": "domain"},
        yaxis={
            "title": "y [m]",
            "range": [ey0, ey1],
            "scaleanchor": "x",
            "scaleratio": 1,
            "constrain": "domain",
            "domain": [0.3, 1.0] if _has_side(motion) else [0.0, 1.0],
        },
        template="plotly_white",
        height=760,
        legend={"orientation": "h", "y": -0.25},
        updatemenus=[
            {
                "type": "buttons",
                "direction": "left",
                "x": 0.0,
                "y": -0.1,
                "xanchor": "left",
                "yanchor": "top",
                "buttons": buttons,
            }
        ],
        sliders=[slider],
        hovermode="closest",
        annotations=[
            {
                "text": "; ".join(motion.notes),
                "showarrow": False,
                "xref": "paper",
                "yref": "paper",
                "x": 0,
                "y": 1.02,
                "xanchor": "left",
                "yanchor": "bottom",
                "font": {"size": 11, "color": "#555555"},
            }
        ]
        if motion.notes
        else [],
    )
    return fig


def _title(motion: Motion, k: int) -> str:
    return f"{motion.title} — {_stamp(motion, k)}"


def write_html(motion: Motion, path: str | os.PathLike[str], max_frames: int = 200) -> Path:
    """Write the interactive view as one self-contained HTML file (plotly.js embedded; atomic write)."""
    from tmr.io.outputs import atomic_write_text

    fig = build_figure(motion, max_frames=max_frames)
    html = fig.to_html(include_plotlyjs=True, full_html=True, auto_play=False, div_id="tmr-view")
    return atomic_write_text(path, html)
