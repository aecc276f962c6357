"""Block diagrams of the docs, drawn while the site builds (matplotlib, SVG): the steering loop online and the
offline path from recorded data to the generated solver. Drawn from the list of blocks and arrows below, so
a renamed part changes one line, not a picture."""

from __future__ import annotations

import io
from dataclasses import dataclass

# online loop (top row) and offline path (bottom row), in axes units (x, y = centre; w, h = size)
_ONLINE_Y, _OFFLINE_Y = 2.6, 0.7
_BOX_H = 0.8
WIDTH = 11.0


@dataclass(frozen=True)
class Block:
    """One box of a diagram: its label and centre (axes units)."""

    key: str
    label: str
    x: float
    y: float
    w: float = 2.2
    online: bool = True


STEERING_BLOCKS: tuple[Block, ...] = (
    Block("traj", "desired trajectory\n$y_{des}$, nominal $u_{nom}$", 1.3, _ONLINE_Y, 2.2),
    Block("qp", "DDPC steering QP\n(generated C, every tick)", 5.0, _ONLINE_Y, 2.5),
    Block("plant", "existing controller\n+ vehicle", 9.2, _ONLINE_Y, 2.2),
    Block("data", "recorded $(u, y)$\n(PRBS collect, log)", 1.3, _OFFLINE_Y, 2.2, online=False),
    Block("hankel", "Hankel matrices\n$U_p, Y_p, U_f, Y_f$", 4.5, _OFFLINE_Y, 2.2, online=False),
    Block("fit", "predictor $G$\n(fit) + codegen", 7.7, _OFFLINE_Y, 2.2, online=False),
)


def _box(ax, b: Block) -> None:  # noqa: ANN001 -- a matplotlib Axes
    from matplotlib.patches import FancyBboxPatch

    face = "#e8f0fe" if b.online else "#f3f3f3"
    ax.add_patch(FancyBboxPatch((b.x - b.w / 2, b.y - _BOX_H / 2), b.w, _BOX_H, boxstyle="round,pad=0.05",
                                facecolor=face, edgecolor="#333333", linewidth=1.2,
                                linestyle="-" if b.online else "--"))
    ax.text(b.x, b.y, b.label, ha="center", va="center", fontsize=9.5)


def _arrow(ax, xy_from, xy_to, label: str = "", dashed: bool = False, label_at=None) -> None:  # noqa: ANN001
    ax.annotate("", xy=xy_to, xytext=xy_from,
                arrowprops={"arrowstyle": "-|>", "color": "#333333", "lw": 1.2,
                            "linestyle": "--" if dashed else "-", "shrinkA": 0, "shrinkB": 0})
    if label:
        x, y = label_at or ((xy_from[0] + xy_to[0]) / 2, (xy_from[1] + xy_to[1]) / 2 + 0.15)
        ax.text(x, y, label, ha="center", va="bottom", fontsize=8.5, color="#1a3d7c")


def steering_loop_svg() -> str:
    """The steering loop as an SVG document: desired trajectory -> DDPC QP -> references -> controller and
    vehicle -> measured output -> back to the QP's window; below, the offline data -> Hankel -> predictor
    path that the generated solver is built from. The same inputs give the same bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with matplotlib.rc_context({"svg.hashsalt": "ddpc-docs", "svg.fonttype": "path"}):
        fig = draw_steering_loop()
        buf = io.StringIO()
        fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
        plt.close(fig)
    return buf.getvalue()


def draw_steering_loop():  # noqa: ANN201 -- a matplotlib Figure (matplotlib is optional)
    """The steering loop diagram as a matplotlib Figure (the caller closes it)."""
    import matplotlib.pyplot as plt

    b = {blk.key: blk for blk in STEERING_BLOCKS}
    fig, ax = plt.subplots(figsize=(WIDTH, 3.6))
    ax.set_xlim(0, WIDTH)
    ax.set_ylim(0, 3.6)
    ax.axis("off")
    for blk in STEERING_BLOCKS:
        _box(ax, blk)
    edge = _BOX_H / 2 + 0.05
    traj, qp, plant, fit = b["traj"], b["qp"], b["plant"], b["fit"]
    _arrow(ax, (traj.x + traj.w / 2 + 0.05, _ONLINE_Y), (qp.x - qp.w / 2 - 0.05, _ONLINE_Y))
    _arrow(ax, (qp.x + qp.w / 2 + 0.05, _ONLINE_Y), (plant.x - plant.w / 2 - 0.05, _ONLINE_Y),
           "steered references $u$")
    # the measured output goes back into the QP's past window (u_ini, y_ini)
    top = _ONLINE_Y + edge
    ax.plot([plant.x, plant.x, qp.x], [top, 3.35, 3.35], color="#333333", lw=1.2)
    _arrow(ax, (qp.x, 3.35), (qp.x, top))
    ax.text((plant.x + qp.x) / 2, 3.38, "measured output $y$ $\\to$ past window $u_{ini}, y_{ini}$", ha="center",
            va="bottom", fontsize=8.5, color="#1a3d7c")
    _arrow(ax, (plant.x + plant.w / 2 + 0.05, _ONLINE_Y), (WIDTH - 0.05, _ONLINE_Y), "", label_at=None)
    ax.text(WIDTH - 0.1, _ONLINE_Y - 0.25, "$y$", ha="right", va="top", fontsize=9)
    for left, right in (("data", "hankel"), ("hankel", "fit")):
        _arrow(ax, (b[left].x + b[left].w / 2 + 0.05, _OFFLINE_Y),
               (b[right].x - b[right].w / 2 - 0.05, _OFFLINE_Y), dashed=True)
    _arrow(ax, (fit.x, _OFFLINE_Y + edge), (qp.x + 0.6, _ONLINE_Y - edge), "solver, once", dashed=True,
           label_at=(fit.x + 0.75, (_OFFLINE_Y + _ONLINE_Y) / 2 - 0.1))
    ax.text(0.2, (_OFFLINE_Y + _ONLINE_Y) / 2 + 0.05, "online, every tick (solid)\noffline, once (dashed)",
            ha="left", va="center", fontsize=8, color="#555555")
    return fig
