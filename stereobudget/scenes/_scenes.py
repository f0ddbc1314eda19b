"""Synthetic stereo pairs with exact ground truth, for tests and for studying failure modes.

A scene is a stack of planar surfaces seen by a rectified camera pair.  Surface ``k`` has
the left-view disparity ``d_k(x, y) = a_k x + b_k y + c_k`` (fronto-parallel when
``a_k = b_k = 0``), a support region (rectangle, ellipse or the whole plane) and a colour
texture defined on the surface itself, parameterised by left-view coordinates.  The texture
is a sum of random sinusoids, so it can be evaluated exactly at the fractional positions
the right view needs.

Both views are ray-cast: a left pixel ``(x, y)`` meets surface ``k`` at ``x`` when
``(x, y)`` lies in its support; a right pixel ``(xr, y)`` meets it at the left-view abscissa
``xl = (xr + c_k + b_k y) / (1 - a_k)`` (the solution of ``xr = xl - d_k(xl, y)``).  Among the
surfaces hit, the one with the largest disparity (nearest) is seen.  Its texture at
``(xl, y)`` is the pixel colour, so the two views agree exactly up to 8-bit rounding.

``make_scene(kind)`` builds one of :data:`SCENE_KINDS`:

``planes``       fronto-parallel layers with occlusions, fractional disparities.
``slanted``      slanted planes in front of a slanted background.
``textureless``  a large constant-colour wall with a few small textured objects.
``fine_texture`` textures between 0.3 and 0.45 cycles/pixel (a stride-5 grid aliases them),
                 integer disparities.
``large_range``  a wide image with disparities beyond 100 pixels.
``ground_plane`` a road seen from a car: a weakly textured ground whose disparity grows
                 from the top row to the bottom one, with upright objects standing on it.
``weak_texture`` a slanted background of texture a few grey levels deep, with slanted
                 objects of ordinary texture in front.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

# New kinds go at the end: a kind's position seeds its layout.
SCENE_KINDS = ("planes", "slanted", "textureless", "fine_texture", "large_range", "ground_plane", "weak_texture")

# kind -> (height, width, max_disp) used when the caller gives none
_DEFAULT_SIZE = {
    "planes": (240, 320, 32),
    "slanted": (240, 320, 32),
    "textureless": (240, 320, 24),
    "fine_texture": (240, 320, 16),
    "large_range": (240, 640, 128),
    "ground_plane": (240, 320, 48),
    "weak_texture": (240, 320, 32),
}

# Texture octaves in cycles per pixel.  Ordinary textures stay below 0.1 cycles/pixel, the
# Nyquist limit of a stride-5 sample grid, so sparse samples can resolve them.
_SMOOTH_OCTAVES = (1 / 48, 1 / 24, 1 / 12)
_FINE_OCTAVES = (0.30, 0.36, 0.42)
_FREQUENCY_JITTER = (0.85, 1.15)  # keeps every ordinary frequency below 0.1 cycles/pixel
_WAVES_PER_OCTAVE = 4
_LUMA_WEIGHTS = np.array([0.299, 0.587, 0.114])


# Serial on purpose: a few multiply-adds per pixel finish before worker threads would pay off.
@njit(cache=True)
def _sum_of_sines_on_grid(rows, cols, sin_col, cos_col, sin_row, cos_row, amplitude, base):
    """(N, 3) float64 texture values at pixels (rows[n], cols[n]).

    Wave k has the phase ``u_k(col) + v_k(row)``; the caller tabulates sin/cos of u over
    columns (K, W) and of v over rows (K, H), so sin(u + v) costs two products per pixel
    instead of a sine.
    """
    n = rows.shape[0]
    out = np.empty((n, 3))
    for p in range(n):
        i = cols[p]
        j = rows[p]
        r = base[0]
        g = base[1]
        b = base[2]
        for k in range(amplitude.shape[0]):
            s = sin_col[k, i] * cos_row[k, j] + cos_col[k, i] * sin_row[k, j]
            r += amplitude[k, 0] * s
            g += amplitude[k, 1] * s
            b += amplitude[k, 2] * s
        out[p, 0] = r
        out[p, 1] = g
        out[p, 2] = b
    return out


@dataclass(frozen=True, eq=False)
class _Texture:
    """Colour ``base + sum_k amplitude[k] * sin(2 pi (fx[k] x + fy[k] y) + phase[k])``, float64."""

    base: np.ndarray        # (3,)
    fx: np.ndarray          # (K,)
    fy: np.ndarray          # (K,)
    phase: np.ndarray       # (K,)
    amplitude: np.ndarray   # (K, 3)

    def evaluate(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """RGB values (N, 3) float64 at arbitrary texture coordinates x, y (N,) (reference path)."""
        angle = (2 * np.pi) * (np.multiply.outer(x, self.fx) + np.multiply.outer(y, self.fy)) + self.phase
        return self.base + np.sin(angle) @ self.amplitude

    def evaluate_affine(self, rows, cols, *, height, width, scale_x=1.0, shear=0.0, shift=0.0) -> np.ndarray:
        """RGB values (N, 3) float64 at pixels (rows, cols) whose texture coordinates are affine.

        The pixel ``(row, col)`` shows the texture at ``x = scale_x * col + shear * row + shift``,
        ``y = row``: the identity for the left view, and the plane's right-to-left map
        ``x = (col + c + b row) / (1 - a)`` for the right view.  Each wave's phase is then a
        sum of a column term and a row term, which are tabulated once.
        """
        two_pi = 2 * np.pi
        col_freq = two_pi * self.fx * scale_x
        row_freq = two_pi * (self.fx * shear + self.fy)
        row_phase = two_pi * self.fx * shift + self.phase
        col_angle = np.multiply.outer(col_freq, np.arange(width, dtype=np.float64))
        row_angle = np.multiply.outer(row_freq, np.arange(height, dtype=np.float64)) + row_phase[:, None]
        return _sum_of_sines_on_grid(rows, cols, np.sin(col_angle), np.cos(col_angle), np.sin(row_angle),
                                     np.cos(row_angle), np.ascontiguousarray(self.amplitude), self.base)

    def curvature_bound(self) -> float:
        """Upper bound of |d^2 T / dx^2| over every channel (grey levels per pixel^2)."""
        if self.fx.size == 0:
            return 0.0
        per_wave = (2 * np.pi * self.fx) ** 2
        return float(np.max(np.abs(self.amplitude).T @ per_wave))


@dataclass(frozen=True, eq=False)
class _Surface:
    """A planar surface: disparity ``a x + b y + c`` over a support region, with a texture."""

    a: float
    b: float
    c: float
    support: tuple          # ("full",) | ("rect", x0, y0, x1, y1) | ("ellipse", cx, cy, rx, ry)
    texture: _Texture

    def disparity(self, x, y):
        return self.a * x + self.b * y + self.c

    def contains(self, x, y):
        kind = self.support[0]
        if kind == "full":
            return np.ones(np.shape(x), dtype=bool)
        if kind == "rect":
            _, x0, y0, x1, y1 = self.support
            return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
        _, cx, cy, rx, ry = self.support
        return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1.0

    def left_abscissa(self, xr, y):
        """Left-view x of the surface point seen at right-view (xr, y): solves xr = xl - d(xl, y)."""
        return (xr + self.c + self.b * y) / (1.0 - self.a)

    @property
    def integer_disparity(self) -> bool:
        return self.a == 0 and self.b == 0 and float(self.c).is_integer()


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """A rendered synthetic stereo pair and its exact ground truth.

    Attributes
    ----------
    kind : str
        One of :data:`SCENE_KINDS`.
    left, right : ndarray, (H, W, 3) uint8 RGB, or (H, W) uint8 when rendered gray
        The two views.
    disparity : ndarray, (H, W), float32
        Exact left-view disparity (left ``(x, y)`` shows the point the right view shows at
        ``(x - d, y)``); finite everywhere.
    nonocc : ndarray, (H, W), bool
        Left pixels whose surface point is visible in the right view (and inside it).
    max_disp : int
        Disparity search range: every disparity lies in ``[0, max_disp]``.
    surface_left, surface_right : ndarray, (H, W), int16
        Index of the surface seen by each pixel of each view (for failure-mode analysis).
    warp_error_bound : float
        Bound, in grey levels, of ``|left - bilinear warp of right by disparity|`` at
        nonocc pixels whose two bilinear neighbours in the right view show the same surface,
        for a noise-free scene: texture curvature / 8 (linear-interpolation error over one
        pixel) plus 1 for the 8-bit rounding of both views.
    seed : int
        Seed the scene was drawn from.
    """

    kind: str
    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonocc: np.ndarray
    max_disp: int
    surface_left: np.ndarray = field(repr=False)
    surface_right: np.ndarray = field(repr=False)
    warp_error_bound: float
    seed: int


# --------------------------------------------------------------------------- random layout

def _random_texture(rng: np.random.Generator, octaves, *, contrast: float = 1.0) -> _Texture:
    base = rng.uniform(80.0, 175.0, size=3)
    if contrast == 0 or not octaves:
        empty = np.zeros(0)
        return _Texture(base, empty, empty, empty, np.zeros((0, 3)))
    magnitude = np.repeat(np.asarray(octaves, dtype=float), _WAVES_PER_OCTAVE)
    magnitude *= rng.uniform(*_FREQUENCY_JITTER, size=magnitude.size)
    magnitude = np.minimum(magnitude, 0.48)  # stay below the pixel Nyquist limit
    direction = rng.uniform(0.0, np.pi, size=magnitude.size)
    amplitude = rng.uniform(0.4, 1.0, size=(magnitude.size, 3)) * rng.choice([-1.0, 1.0], size=(magnitude.size, 3))
    # Scale so the texture never leaves [0, 255]: rounding is then the only distortion.
    headroom = np.minimum(base, 255.0 - base) - 2.0
    amplitude *= contrast * np.min(headroom / np.abs(amplitude).sum(axis=0))
    return _Texture(base=base, fx=magnitude * np.cos(direction), fy=magnitude * np.sin(direction),
                    phase=rng.uniform(0.0, 2 * np.pi, size=magnitude.size), amplitude=amplitude)


def _random_support(rng, height, width, *, size_range, centre_x_range=None):
    """A rectangle or an ellipse whose size is a fraction of the image size."""
    lo_x, hi_x = centre_x_range if centre_x_range is not None else (0.15 * width, 0.85 * width)
    cx = rng.uniform(lo_x, max(lo_x, hi_x))
    cy = rng.uniform(0.2 * height, 0.8 * height)
    half_w = 0.5 * width * rng.uniform(*size_range)
    half_h = 0.5 * height * rng.uniform(*size_range)
    if rng.random() < 0.5:
        return ("rect", cx - half_w, cy - half_h, cx + half_w, cy + half_h)
    return ("ellipse", cx, cy, half_w, half_h)


def _support_box(support, height, width):
    if support[0] == "full":
        return 0.0, 0.0, float(width - 1), float(height - 1)
    if support[0] == "rect":
        return support[1:]
    _, cx, cy, rx, ry = support
    return cx - rx, cy - ry, cx + rx, cy + ry


def _slanted_plane(rng, box, centre_d, spread):
    """Plane with disparity ``centre_d`` at the box centre that varies by at most ``spread`` across it."""
    x0, y0, x1, y1 = box
    theta = rng.uniform(0.0, 2 * np.pi)
    # d varies by |a| w + |b| h across the box; split the spread between the two directions.
    a = 0.5 * spread * math.cos(theta) / max(x1 - x0, 1.0)
    b = 0.5 * spread * math.sin(theta) / max(y1 - y0, 1.0)
    c = centre_d - a * 0.5 * (x0 + x1) - b * 0.5 * (y0 + y1)
    return a, b, c


def _layout(kind: str, rng: np.random.Generator, height: int, width: int, max_disp: float) -> list[_Surface]:
    surfaces: list[_Surface] = []
    if kind in ("planes", "large_range"):
        n_objects = 4
        surfaces.append(_Surface(0.0, 0.0, rng.uniform(0.1, 0.2) * max_disp, ("full",),
                                 _random_texture(rng, _SMOOTH_OCTAVES)))
        depths = np.linspace(0.35, 0.93, n_objects) * max_disp + rng.uniform(-0.03, 0.03, n_objects) * max_disp
        for d in depths:
            # keep each object mostly inside the right view too (x - d >= 0)
            support = _random_support(rng, height, width, size_range=(0.15, 0.35),
                                      centre_x_range=(min(d + 0.1 * width, 0.8 * width), 0.85 * width))
            surfaces.append(_Surface(0.0, 0.0, float(d), support, _random_texture(rng, _SMOOTH_OCTAVES)))
    elif kind == "slanted":
        box = (0.0, 0.0, float(width - 1), float(height - 1))
        a, b, c = _slanted_plane(rng, box, 0.25 * max_disp, 0.25 * max_disp)
        surfaces.append(_Surface(a, b, c, ("full",), _random_texture(rng, _SMOOTH_OCTAVES)))
        for centre_d in (0.5, 0.65, 0.8):
            support = _random_support(rng, height, width, size_range=(0.2, 0.4))
            a, b, c = _slanted_plane(rng, _support_box(support, height, width), centre_d * max_disp,
                                     0.25 * max_disp)
            surfaces.append(_Surface(a, b, c, support, _random_texture(rng, _SMOOTH_OCTAVES)))
    elif kind == "textureless":
        surfaces.append(_Surface(0.0, 0.0, rng.uniform(0.25, 0.35) * max_disp, ("full",),
                                 _random_texture(rng, _SMOOTH_OCTAVES, contrast=0.0)))
        for d in np.linspace(0.5, 0.9, 4) * max_disp:
            support = _random_support(rng, height, width, size_range=(0.06, 0.12))
            surfaces.append(_Surface(0.0, 0.0, float(d), support, _random_texture(rng, _SMOOTH_OCTAVES)))
    elif kind == "fine_texture":
        surfaces.append(_Surface(0.0, 0.0, float(round(0.2 * max_disp)), ("full",),
                                 _random_texture(rng, _FINE_OCTAVES)))
        for d in np.linspace(0.45, 0.9, 3) * max_disp:
            support = _random_support(rng, height, width, size_range=(0.2, 0.35))
            surfaces.append(_Surface(0.0, 0.0, float(round(d)), support, _random_texture(rng, _FINE_OCTAVES)))
    elif kind == "ground_plane":
        # The ground: d = b y + c, from 5 % of the range at the top row to 85 % at the bottom.
        top, bottom = 0.05 * max_disp, 0.85 * max_disp
        b = (bottom - top) / (height - 1)
        surfaces.append(_Surface(0.0, b, top, ("full",), _random_texture(rng, _SMOOTH_OCTAVES, contrast=0.3)))
        for row in np.linspace(0.45, 0.8, 3) * height:
            # An upright object standing on the ground at ``row``: the ground's disparity there.
            d = b * row + top
            half_w = 0.5 * width * rng.uniform(0.1, 0.2)
            half_h = 0.5 * height * rng.uniform(0.15, 0.3)
            cx = rng.uniform(max(d + half_w, 0.15 * width), 0.85 * width)
            support = ("rect", cx - half_w, row - 2 * half_h, cx + half_w, row)
            surfaces.append(_Surface(0.0, 0.0, float(d), support, _random_texture(rng, _SMOOTH_OCTAVES)))
    elif kind == "weak_texture":
        box = (0.0, 0.0, float(width - 1), float(height - 1))
        a, b, c = _slanted_plane(rng, box, 0.3 * max_disp, 0.3 * max_disp)
        surfaces.append(_Surface(a, b, c, ("full",), _random_texture(rng, _SMOOTH_OCTAVES, contrast=0.05)))
        for centre_d in (0.6, 0.8):
            support = _random_support(rng, height, width, size_range=(0.15, 0.3))
            a, b, c = _slanted_plane(rng, _support_box(support, height, width), centre_d * max_disp,
                                     0.2 * max_disp)
            surfaces.append(_Surface(a, b, c, support, _random_texture(rng, _SMOOTH_OCTAVES)))
    else:
        raise ValueError(f"unknown synthetic scene kind {kind!r}; expected one of {SCENE_KINDS}")
    return surfaces


# --------------------------------------------------------------------------- rendering

def _front_surface_left(surfaces, x, y):
    """Index (int16) and disparity (float64) of the nearest surface at left-view points (x, y)."""
    best_d = np.full(x.shape, -np.inf)
    best = np.full(x.shape, -1, dtype=np.int16)
    for index, surface in enumerate(surfaces):
        d = surface.disparity(x, y)
        # strict ">" gives ties to the earlier surface, in both views alike
        take = surface.contains(x, y) & (d > best_d)
        best_d[take] = d[take]
        best[take] = index
    return best, best_d


def _front_surface_right(surfaces, xr, y):
    """Index (int16), left-view abscissa and disparity of the nearest surface at right-view (xr, y)."""
    best_d = np.full(xr.shape, -np.inf)
    best_xl = np.full(xr.shape, np.nan)
    best = np.full(xr.shape, -1, dtype=np.int16)
    for index, surface in enumerate(surfaces):
        xl = surface.left_abscissa(xr, y)
        d = surface.disparity(xl, y)
        take = surface.contains(xl, y) & (d > best_d)
        best_d[take] = d[take]
        best_xl[take] = xl[take]
        best[take] = index
    return best, best_xl, best_d


def _shade(surfaces, labels, *, right_view: bool) -> np.ndarray:
    """Float64 (H, W, 3) image: each pixel's surface texture, for the left or the right view."""
    height, width = labels.shape
    image = np.zeros(labels.shape + (3,))
    for index, surface in enumerate(surfaces):
        rows, cols = np.nonzero(labels == index)
        if rows.size == 0:
            continue
        if right_view:
            # right pixel (row, col) shows the surface at x = (col + c + b row) / (1 - a)
            inv = 1.0 / (1.0 - surface.a)
            mapping = dict(scale_x=inv, shear=surface.b * inv, shift=surface.c * inv)
        else:
            mapping = {}
        image[rows, cols] = surface.texture.evaluate_affine(rows, cols, height=height, width=width, **mapping)
    return image


def _to_uint8(image: np.ndarray, *, gray: bool) -> np.ndarray:
    if gray:
        image = image @ _LUMA_WEIGHTS
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def make_scene(kind: str, *, height: int | None = None, width: int | None = None,
               max_disp: int | None = None, seed: int = 0, noise_sigma: float = 0.0,
               gray: bool = False) -> SyntheticScene:
    """Render a synthetic stereo pair with exact left-view ground truth.

    Parameters
    ----------
    kind : str
        One of :data:`SCENE_KINDS`.
    height, width : int, optional
        Image size (>= 32); defaults 240 x 320 (640 wide for ``large_range``).
    max_disp : int, optional
        Disparity search range; the layout is scaled to it.  Defaults: planes/slanted/weak_texture 32,
        ground_plane 48,
        textureless 24, fine_texture 16, large_range 128.
    seed : int
        Seed of the random layout, textures and noise; equal seeds give identical scenes.
    noise_sigma : float
        Standard deviation (grey levels) of independent Gaussian noise added to each view.
    gray : bool
        Render single-channel luminance images instead of RGB.

    Returns
    -------
    SyntheticScene
    """
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown synthetic scene kind {kind!r}; expected one of {SCENE_KINDS}")
    default_h, default_w, default_max = _DEFAULT_SIZE[kind]
    height = default_h if height is None else int(height)
    width = default_w if width is None else int(width)
    max_disp = default_max if max_disp is None else int(max_disp)
    if height < 32 or width < 32:
        raise ValueError(f"synthetic scenes need at least 32x32 pixels, got {width}x{height}")
    if not 4 <= max_disp < width // 2:
        raise ValueError(f"max_disp must be in [4, width/2) = [4, {width // 2}), got {max_disp}")
    if noise_sigma < 0:
        raise ValueError(f"noise_sigma must be >= 0, got {noise_sigma}")

    rng = np.random.default_rng([seed, SCENE_KINDS.index(kind)])
    surfaces = _layout(kind, rng, height, width, float(max_disp))

    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    surface_left, disparity = _front_surface_left(surfaces, x, y)
    surface_right, _, _ = _front_surface_right(surfaces, x, y)
    left = _shade(surfaces, surface_left, right_view=False)
    right = _shade(surfaces, surface_right, right_view=True)

    # A left pixel is non-occluded when its point lands inside the right image and the
    # right view's nearest surface at that (fractional) position is the same one.
    xr = x - disparity
    seen_from_right, _, _ = _front_surface_right(surfaces, xr, y)
    nonocc = (xr >= 0) & (xr <= width - 1) & (seen_from_right == surface_left)

    if noise_sigma > 0:
        noise_rng = np.random.default_rng([seed, SCENE_KINDS.index(kind), 1])
        left = left + noise_rng.normal(0.0, noise_sigma, left.shape)
        right = right + noise_rng.normal(0.0, noise_sigma, right.shape)

    visible = np.unique(np.concatenate([surface_left.ravel(), surface_right.ravel()]))
    curvature = max((surfaces[i].texture.curvature_bound() / (1.0 - surfaces[i].a) ** 2
                     for i in visible if not surfaces[i].integer_disparity), default=0.0)
    disparity = disparity.astype(np.float32)
    if disparity.min() < 0 or disparity.max() > max_disp:
        raise AssertionError(f"scene layout produced disparities outside [0, {max_disp}]")
    return SyntheticScene(kind=kind, left=_to_uint8(left, gray=gray), right=_to_uint8(right, gray=gray),
                          disparity=disparity, nonocc=nonocc, max_disp=max_disp,
                          surface_left=surface_left, surface_right=surface_right,
                          warp_error_bound=curvature / 8.0 + 1.0, seed=int(seed))
