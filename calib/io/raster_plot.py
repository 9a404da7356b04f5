"""A few plot panels drawn with Pillow directly: what ``calib run``'s figures need, at a fraction
of matplotlib's cost (its import and its per-axes tick and text machinery cost ~1 s of CPU for the
summary figure against ~0.1 s here; docs/speed.md "`calib run`'s figures without matplotlib").

A :class:`Canvas` is a white RGB image drawn at ``SUPERSAMPLE`` times its final size (1 for a very
large one) and reduced by a box filter when saved (anti-aliased edges without per-primitive
anti-aliasing); a :class:`Panel` is one axes on it: a data rectangle with linear or log10 axes
(equal aspect on request), filled steps, dots (all of one panel in one numpy pass), crosses,
arrows, lines, vertical and horizontal lines, then the frame, ticks at 1-2-2.5-5 steps (decades
on a log axis), labels, title and legend.

Coordinates: data (x, y) map to the panel's pixel rectangle, x to the right and y up; pixel
coordinates are those of the supersampled canvas, (column, row) from its top-left corner. Sizes
given to the public methods (radii, line widths, font sizes) are final-image pixels.

    >>> import numpy as np
    >>> from calib.io.raster_plot import Canvas
    >>> c = Canvas(200, 150)
    >>> p = c.panel((0, 0, 200, 150), xlim=(0, 2), ylim=(0, 1), margins=(40, 10, 20, 30))
    >>> p.stairs([0.5, 0.8], [0, 1, 2], color=(31, 119, 180))
    >>> p.finish(xlabel="x", ylabel="y", title="t")
    >>> c.image().size
    (200, 150)
"""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

#: The canvas is drawn at this multiple of its final size (anti-aliasing by a box reduction) ...
SUPERSAMPLE = 2
#: ... up to this many final pixels; a larger one (the per-pose figure of 100 views: 28800 x 562)
#: is drawn at its final size, so that its drawing stays ~50 MB instead of ~200.
SUPERSAMPLE_MAX_PIXELS = 4_000_000
#: matplotlib's default colour cycle's first colour ("C0") and its "red".
C0, RED, BLACK, GREY = (31, 119, 180), (255, 0, 0), (0, 0, 0), (204, 204, 204)
#: matplotlib's default colour cycle ("C0" ... "C9", tab10).
CYCLE = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
         (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
#: viridis (van der Walt & Smith, matplotlib's default colour map, CC0) sampled at 17 evenly spaced
#: points, 0-255 RGB; linear between them it is within 6/255 of the 256-entry map.
_VIRIDIS = np.array([[68, 1, 84], [72, 24, 106], [71, 45, 123], [66, 64, 134], [59, 82, 139], [51, 99, 141],
                     [44, 114, 142], [38, 130, 142], [33, 145, 140], [31, 160, 136], [40, 174, 128],
                     [63, 188, 115], [94, 201, 98], [132, 212, 75], [173, 220, 48], [216, 226, 25],
                     [253, 231, 37]], dtype=float)
_MINUS = "\u2212"
_SUPERSCRIPT = str.maketrans("-0123456789", "\u207b\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079")
_fonts: dict = {}


def viridis(t) -> np.ndarray:
    """Colours of viridis at ``t`` (any shape, clipped to [0, 1]): uint8 (..., 3)."""
    t = np.clip(np.asarray(t, dtype=float), 0.0, 1.0)
    k = np.linspace(0.0, 1.0, len(_VIRIDIS))
    return np.stack([np.interp(t, k, _VIRIDIS[:, c]) for c in range(3)], axis=-1).round().astype(np.uint8)


def font(size_px: float, scale: int = SUPERSAMPLE):
    """DejaVu Sans (matplotlib's default font, from its data folder: found, not imported) at
    ``size_px`` final-image pixels drawn at ``scale``; Pillow's own scalable font where it is
    missing. Cached."""
    size = max(1, round(size_px * scale))
    if size not in _fonts:
        spec = importlib.util.find_spec("matplotlib")
        ttf = Path(spec.origin).parent / "mpl-data/fonts/ttf/DejaVuSans.ttf" if spec and spec.origin else None
        _fonts[size] = (ImageFont.truetype(str(ttf), size) if ttf is not None and ttf.is_file()
                        else ImageFont.load_default(size=size))
    return _fonts[size]


def nice_ticks(lo: float, hi: float, n: int = 5) -> tuple[np.ndarray, int]:
    """At most ``n`` + 1 ticks in [lo, hi] at the smallest 1, 2, 2.5 or 5 x 10^k step that keeps
    them that few (matplotlib's MaxNLocator), and the decimals that show them apart.
    Returns (ticks, decimals)."""
    span = hi - lo
    if not span > 0 or not np.isfinite(span):
        return np.array([lo]), 2
    mag = 10.0 ** (math.floor(math.log10(span / max(n, 1))) - 1)
    for step, m in ((m * mag * 10.0 ** e, m) for e in range(4) for m in (1, 2, 2.5, 5)):
        first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        if last - first + 1 <= n + 1:
            break
    ticks = np.arange(first, last + 1) * step
    decimals = max(0, -math.floor(math.log10(step) + 1e-9) + (1 if m == 2.5 else 0))
    return ticks, decimals


def tick_label(v: float, decimals: int) -> str:
    """``v`` with ``decimals`` decimals, a typographic minus, no negative zero."""
    s = f"{v:.{decimals}f}"
    return "0" if float(s) == 0 else s.replace("-", _MINUS)


class Canvas:
    """A white image of ``width`` x ``height`` final pixels, drawn at ``s`` (:data:`SUPERSAMPLE`,
    or 1 above :data:`SUPERSAMPLE_MAX_PIXELS`) times that."""

    def __init__(self, width: int, height: int):
        self.size = (int(width), int(height))
        self.s = SUPERSAMPLE if self.size[0] * self.size[1] <= SUPERSAMPLE_MAX_PIXELS else 1
        self.im = Image.new("RGB", (self.size[0] * self.s, self.size[1] * self.s), "white")
        self.draw = ImageDraw.Draw(self.im)

    def panel(self, cell, xlim, ylim, *, ylog: bool = False, xlog: bool = False, margins=(75, 15, 45, 50),
              equal: bool = False) -> "Panel":
        """An axes in ``cell`` = (left, top, width, height) final pixels, its data rectangle inset by
        ``margins`` = (left, right, top, bottom) final pixels; ``xlim``, ``ylim``: data ranges
        (``ylog`` / ``xlog``: that axis on a log10 scale, its limits > 0; ``ylim`` = (bottom, top):
        (H, 0) puts 0 at the top, as an image's rows). ``equal``: the rectangle shrunk about its
        centre so that one data unit is as long on x as on y (matplotlib's ``set_aspect("equal")``)."""
        s = self.s
        l, t, w, h = cell
        ml, mr, mt, mb = margins
        box = [round((l + ml) * s), round((t + mt) * s), round((l + w - mr) * s), round((t + h - mb) * s)]
        if equal:
            bw, bh = box[2] - box[0], box[3] - box[1]
            ratio = abs(ylim[1] - ylim[0]) / max(abs(xlim[1] - xlim[0]), 1e-300)      # data height / width
            if bh > bw * ratio:
                cut = round((bh - bw * ratio) / 2)
                box[1], box[3] = box[1] + cut, box[3] - cut
            else:
                cut = round((bw - bh / ratio) / 2)
                box[0], box[2] = box[0] + cut, box[2] - cut
        return Panel(self, tuple(box), xlim, ylim, ylog, xlog)

    def text(self, xy, text: str, size_px: float, anchor: str = "la", fill=BLACK, angle: int = 0) -> None:
        """``text`` at canvas pixel ``xy`` (Pillow's ``anchor``; ``angle`` 90: read bottom to top)."""
        f = font(size_px, self.s)
        if angle == 0:
            self.draw.text(xy, text, font=f, fill=fill, anchor=anchor)
            return
        l, t, r, b = self.draw.textbbox((0, 0), text, font=f, anchor="lt")
        tile = Image.new("L", (r - l + 2, b - t + 2), 0)
        ImageDraw.Draw(tile).text((1 - l, 1 - t), text, font=f, fill=255, anchor="lt")
        tile = tile.rotate(angle, expand=True)
        x, y = xy          # anchor "mm": the rotated text centred on xy
        pos = (round(x - tile.width / 2), round(y - tile.height / 2))
        self.im.paste(Image.new("RGB", tile.size, fill), pos, tile)

    def image(self) -> Image.Image:
        """The final image (box-reduced from the supersampled drawing; the drawing itself, not a
        copy, when it is drawn at the final size)."""
        return self.im.reduce(self.s) if self.s > 1 else self.im


class Panel:
    """One axes on a :class:`Canvas` (see :meth:`Canvas.panel`); data drawn before :meth:`finish`
    are clipped to the data rectangle."""

    def __init__(self, canvas: Canvas, box, xlim, ylim, ylog: bool = False, xlog: bool = False):
        self.canvas, self.box, self.ylog, self.xlog, self.s = canvas, box, ylog, xlog, canvas.s
        self.xlim, self.ylim = tuple(map(float, xlim)), tuple(map(float, ylim))
        self.w, self.h = box[2] - box[0], box[3] - box[1]
        self.im = Image.new("RGB", (self.w, self.h), "white")      # the data layer: clipped by its size
        self.draw = ImageDraw.Draw(self.im)
        self.legend_items: list = []

    @staticmethod
    def _scaled(values, lim, log: bool):
        values = np.asarray(values, dtype=float)
        if not log:
            return values, lim
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log10(np.where(values > 0, values, np.nan)), tuple(math.log10(v) for v in lim)

    def px(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Data (x, y) -> pixel (column, row) in the data layer (float; a log axis' value <= 0 maps
        far outside the panel: left of it, or below it)."""
        fx, (x0, x1) = self._scaled(x, self.xlim, self.xlog)
        fy, (y0, y1) = self._scaled(y, self.ylim, self.ylog)
        u = (fx - x0) / (x1 - x0) * self.w
        v = (1.0 - (fy - y0) / (y1 - y0)) * self.h
        return np.where(np.isnan(u), -self.w * 4.0, u), np.where(np.isnan(v), self.h * 4.0, v)

    def dots(self, x, y, colors, radius_px: float) -> None:
        """Filled discs of ``radius_px`` at (x, y), ``colors`` (N, 3) uint8 or one colour; drawn in
        order (a later dot covers an earlier one), in one numpy pass over the disc's pixels."""
        u, v = self.px(x, y)
        n = len(u)
        if n == 0:
            return
        colors = np.broadcast_to(np.asarray(colors, dtype=np.uint8), (n, 3))
        r = radius_px * self.s
        k = np.arange(-math.ceil(r), math.ceil(r) + 1)
        du, dv = np.meshgrid(k, k)
        inside = du ** 2 + dv ** 2 <= r * r
        cu = (np.round(u).astype(np.int64)[:, None] + du[inside]).ravel()
        cv = (np.round(v).astype(np.int64)[:, None] + dv[inside]).ravel()
        who = np.repeat(np.arange(n), inside.sum())
        ok = (cu >= 0) & (cu < self.w) & (cv >= 0) & (cv < self.h)
        flat = cv[ok] * self.w + cu[ok]
        top = np.full(self.w * self.h, -1, dtype=np.int64)
        np.maximum.at(top, flat, who[ok])       # the last dot drawn on a pixel is the one seen
        hit = top >= 0
        a = np.asarray(self.im).reshape(-1, 3).copy()
        a[hit] = colors[top[hit]]
        self.im = Image.fromarray(a.reshape(self.h, self.w, 3))
        self.draw = ImageDraw.Draw(self.im)

    def crosses(self, x, y, color, size_px: float = 5.0, width_px: float = 1.3) -> None:
        """'x' markers of ``size_px`` across at (x, y)."""
        u, v = self.px(x, y)
        d, w = size_px * self.s / 2, max(1, round(width_px * self.s))
        for a, b in zip(u, v):
            self.draw.line([(a - d, b - d), (a + d, b + d)], fill=color, width=w)
            self.draw.line([(a - d, b + d), (a + d, b - d)], fill=color, width=w)

    def arrows(self, x, y, dx, dy, colors, width_px: float = 1.0, head_px: float = 5.0) -> None:
        """Arrows from (x, y) to (x + dx, y + dy), data units (matplotlib's ``quiver`` with
        ``angles="xy", scale_units="xy"``): a shaft ``width_px`` wide and a head up to ``head_px``
        long (at most 60 % of a short arrow); ``colors``: one colour or (N, 3)."""
        u0, v0 = self.px(x, y)
        u1, v1 = self.px(np.asarray(x, float) + dx, np.asarray(y, float) + dy)
        colors = np.broadcast_to(np.asarray(colors, dtype=np.uint8), (len(u0), 3))
        w = max(1, round(width_px * self.s))
        length = np.hypot(u1 - u0, v1 - v0)
        head = np.minimum(head_px * self.s, 0.6 * length)
        with np.errstate(invalid="ignore", divide="ignore"):
            eu, ev = (u1 - u0) / length, (v1 - v0) / length
        for k in np.flatnonzero(length > 0.5):
            c = tuple(int(a) for a in colors[k])
            bu, bv = u1[k] - head[k] * eu[k], v1[k] - head[k] * ev[k]      # the head's base centre
            self.draw.line([(u0[k], v0[k]), (bu, bv)], fill=c, width=w)
            hw = max(0.45 * head[k], 0.75 * w)
            self.draw.polygon([(u1[k], v1[k]), (bu - hw * ev[k], bv + hw * eu[k]), (bu + hw * ev[k], bv - hw * eu[k])],
                              fill=c)

    def stairs(self, values, edges, color, baseline: float = 0.0) -> None:
        """Filled steps: ``values[i]`` over [edges[i], edges[i+1]] down to ``baseline`` (one polygon)."""
        values, edges = np.asarray(values, dtype=float), np.asarray(edges, dtype=float)
        xs = np.concatenate([[edges[0]], np.repeat(edges[1:-1], 2), [edges[-1]]])
        ys = np.repeat(values, 2)
        u, v = self.px(np.concatenate([[edges[0]], xs, [edges[-1]]]), np.concatenate([[baseline], ys, [baseline]]))
        v = np.clip(v, -2.0 * self.h, 3.0 * self.h)
        self.draw.polygon(list(zip(u.tolist(), v.tolist())), fill=color)

    def line(self, x, y, color, width_px: float = 1.5, dash_px: float | None = None) -> None:
        """A polyline through (x, y) (dashed with ``dash_px`` dashes and gaps when given)."""
        u, v = self.px(x, y)
        v = np.clip(v, -2.0 * self.h, 3.0 * self.h)
        w = max(1, round(width_px * self.s))
        if dash_px is None:
            self.draw.line(list(zip(u.tolist(), v.tolist())), fill=color, width=w, joint="curve")
            return
        d = dash_px * self.s
        for (a0, b0), (a1, b1) in zip(zip(u, v), zip(u[1:], v[1:])):
            length = math.hypot(a1 - a0, b1 - b0)
            for s in np.arange(0.0, length, 2 * d):
                e = min(s + d, length)
                self.draw.line([(a0 + (a1 - a0) * s / length, b0 + (b1 - b0) * s / length),
                                (a0 + (a1 - a0) * e / length, b0 + (b1 - b0) * e / length)], fill=color, width=w)

    def vline(self, x, color, width_px: float = 1.5, dash_px: float | None = 4.0) -> None:
        """A vertical line at data ``x`` over the panel's height."""
        y0, y1 = self.ylim
        self.line([x, x], [y0, y1], color, width_px, dash_px)

    def hline(self, y, color, width_px: float = 1.0) -> None:
        """A horizontal line at data ``y`` over the panel's width."""
        v = float(self.px([self.xlim[0]], [y])[1][0])
        self.draw.line([(0, v), (self.w, v)], fill=color, width=max(1, round(width_px * self.s)))

    def legend(self, label: str, kind: str, color) -> None:
        """A legend entry: ``kind`` "patch" (filled square), "line", "cross" or "dot"."""
        self.legend_items.append((label, kind, color))

    def _ticks(self, lo, hi, n, log, plain: bool = False):
        """[(value, label)]: ``n`` 0: none; linear: :func:`nice_ticks`; log: the decades, labelled
        10^k, or (``plain``) in plain numbers with 2, 3 and 5 x 10^k between them where fewer than
        three decades are in view."""
        lo, hi = min(lo, hi), max(lo, hi)
        if n == 0:
            return []
        if not log:
            t, d = nice_ticks(lo, hi, n)
            return [(v, tick_label(v, d)) for v in t]
        exps = range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
        mants = (1, 2, 3, 5) if plain and math.log10(hi / lo) < 2 else (1,)
        ticks = [m * 10.0 ** e for e in exps for m in mants if lo * (1 - 1e-9) <= m * 10.0 ** e <= hi * (1 + 1e-9)]
        return [(v, f"{v:g}" if plain else "10" + str(round(math.log10(v))).translate(_SUPERSCRIPT)) for v in ticks]

    def finish(self, *, xlabel="", ylabel="", title="", xticks: int = 5, yticks: int = 5, legend_loc="upper right",
               font_px: float = 12.5, title_px: float = 15.0, legend_px: float = 10.0, plain_log: bool = False) -> None:
        """Paste the data layer, then draw the frame, ticks and their labels (``xticks``/``yticks``:
        about how many, 0: none; ``plain_log``: a log axis labelled in plain numbers), the axis
        labels, the title (lines split on newlines, centred above) and the legend."""
        c, s = self.canvas, self.s
        l, t, r, b = self.box
        c.im.paste(self.im, (l, t))
        c.draw.rectangle((l - s // 2, t - s // 2, r + s // 2 - 1, b + s // 2 - 1), outline=BLACK, width=s)
        tick, gap = round(3.5 * s), round(3.5 * s)
        for v, text in self._ticks(*self.xlim, xticks, self.xlog, plain_log):
            u = l + self.px([v], [self.ylim[0]])[0][0]
            c.draw.line([(u, b), (u, b + tick)], fill=BLACK, width=s)
            c.text((u, b + tick + gap), text, font_px, anchor="mt")
        ylabels = self._ticks(*self.ylim, yticks, self.ylog, plain_log)
        for v, text in ylabels:
            y = t + self.px([self.xlim[0]], [v])[1][0]
            c.draw.line([(l - tick, y), (l, y)], fill=BLACK, width=s)
            c.text((l - tick - gap, y), text, font_px, anchor="rm")
        if xlabel:
            c.text(((l + r) / 2, b + tick + gap + round(1.6 * font_px * s)), xlabel, font_px, anchor="mt")
        if ylabel:
            widest = max((c.draw.textlength(lab, font=font(font_px, s)) for _, lab in ylabels), default=0)
            c.text((l - tick - 2 * gap - widest - round(0.7 * font_px * s), (t + b) / 2), ylabel, font_px,
                   anchor="mm", angle=90)
        for k, line in enumerate(reversed(title.split("\n"))):
            c.text(((l + r) / 2, t - round(0.5 * title_px * s) - k * round(1.2 * title_px * s)), line, title_px,
                   anchor="md")
        self._draw_legend(legend_loc, legend_px)

    def _draw_legend(self, loc: str, size_px: float) -> None:
        if not self.legend_items:
            return
        c, s = self.canvas, self.s
        f = font(size_px, s)
        row, key, pad = round(1.4 * size_px * s), round(2.0 * size_px * s), round(0.5 * size_px * s)
        width = key + pad * 3 + max(c.draw.textlength(label, font=f) for label, _, _ in self.legend_items)
        height = row * len(self.legend_items) + pad
        l, t, r, _ = self.box
        x0 = (r - pad - width) if loc.endswith("right") else (l + pad)
        y0 = t + pad
        c.draw.rounded_rectangle((x0, y0, x0 + width, y0 + height), radius=2 * s, fill="white", outline=GREY, width=s)
        for k, (label, kind, color) in enumerate(self.legend_items):
            ym, xk = y0 + pad / 2 + row * (k + 0.5), x0 + pad
            if kind == "patch":
                c.draw.rectangle((xk, ym - 0.35 * row, xk + key, ym + 0.35 * row), fill=color)
            elif kind == "line":
                c.draw.line([(xk, ym), (xk + key, ym)], fill=color, width=round(1.5 * s))
            elif kind == "cross":
                d, m = 0.25 * row, xk + key / 2
                c.draw.line([(m - d, ym - d), (m + d, ym + d)], fill=color, width=round(1.3 * s))
                c.draw.line([(m - d, ym + d), (m + d, ym - d)], fill=color, width=round(1.3 * s))
            else:
                d, m = 0.2 * row, xk + key / 2
                c.draw.ellipse((m - d, ym - d, m + d, ym + d), fill=color)
            c.draw.text((xk + key + pad, ym), label, font=f, fill=BLACK, anchor="lm")
