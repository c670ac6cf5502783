"""The real camera's image pipeline: an RGB frame from under the glass table -> the policy's 64x64 mask.

    mask = MaskPipeline(crop=(40, 120, 440, 520), flip_vertical=True, open_size=5, close_size=5).to_mask(rgb)

Stages, in order (each configured by a field of `MaskPipeline`):
1. crop: `crop = (top, left, bottom, right)` in pixels of the raw frame, half-open; choose it so the
   cropped view covers the simulated camera's field of view (65 degrees vertical from 0.5 m below the
   table top: a 0.64 m square centred under (0.4, 0.0)).
2. flip: `flip_horizontal` (mirror columns), `flip_vertical` (mirror rows), to reach the simulator's pixel
   convention: columns grow with world +x, rows with world +y (see `mjx_push.mask_geometry`).
3. colour threshold: a pixel is the object when every channel lies within [lower, upper] (inclusive), in
   `color_space` "rgb" (0..255 each) or "hsv" (hue in degrees 0..360, saturation and value 0..1). A hue
   range with lower > upper wraps through 0 (e.g. red: lower hue 340, upper hue 20).
4. morphology: binary opening (`open_size`, removes speckle smaller than the kernel) then closing
   (`close_size`, fills holes and gaps smaller than the kernel), square kernels of odd size in pixels of
   the cropped frame; 1 disables a stage. Pixels outside the frame count as background for dilation and
   as object for erosion, so neither stage eats into a silhouette that touches the border.
5. resize to 64x64: "area" sets an output pixel when at least `area_threshold` of its footprint is object
   (any scale factor, integer or not); "nearest" samples the source pixel under the output pixel's centre.

The default thresholds are the simulator's colour filter (`mjx_push.export.cpu_env.render_filter`: the blue
emissive object; in HSV a blue hue band 210..270 degrees), with no crop, flip or morphology, so a 64x64
render of the "under_table" camera maps to the simulator's mask unchanged. Pure NumPy (no OpenCV, no SciPy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mjx_push import scene
from mjx_push.errors import ConfigError

OUT = scene.IMAGE_SIZE
COLOR_SPACES = ("rgb", "hsv")
RESIZE_MODES = ("area", "nearest")
_RANGES = {"rgb": (255.0, 255.0, 255.0), "hsv": (360.0, 1.0, 1.0)}
# The simulator's blue object: rgb = render_filter's B > 128, R < 80, G < 80; hsv = a blue hue band.
DEFAULT_THRESHOLDS = {
    "rgb": ((0.0, 0.0, 129.0), (79.0, 79.0, 255.0)),
    "hsv": ((210.0, 0.6, 0.5), (270.0, 1.0, 1.0)),
}


def _triple(name: str, v) -> tuple[float, float, float]:
    try:
        t = tuple(float(x) for x in v)
    except TypeError:
        raise ConfigError(f"{name} must be three numbers, got {v!r}") from None
    if len(t) != 3 or not all(np.isfinite(t)):
        raise ConfigError(f"{name} must be three finite numbers, got {v!r}")
    return t


@dataclass(frozen=True)
class MaskPipeline:
    color_space: str = "rgb"
    lower: tuple[float, float, float] | None = None  # inclusive; None: DEFAULT_THRESHOLDS[color_space]
    upper: tuple[float, float, float] | None = None
    crop: tuple[int, int, int, int] | None = None  # (top, left, bottom, right), half-open pixel box
    flip_horizontal: bool = False
    flip_vertical: bool = False
    open_size: int = 1  # odd kernel side in pixels; 1 = no opening
    close_size: int = 1  # odd kernel side in pixels; 1 = no closing
    resize: str = "area"
    area_threshold: float = 0.5  # "area": fraction of an output pixel's footprint that must be object

    def __post_init__(self):
        if self.color_space not in COLOR_SPACES:
            raise ConfigError(f"color_space must be one of {COLOR_SPACES}, got {self.color_space!r}")
        d_lower, d_upper = DEFAULT_THRESHOLDS[self.color_space]
        lower = _triple("lower", d_lower if self.lower is None else self.lower)
        upper = _triple("upper", d_upper if self.upper is None else self.upper)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        top = _RANGES[self.color_space]
        for name, t in (("lower", lower), ("upper", upper)):
            for k, (x, hi) in enumerate(zip(t, top)):
                if not 0.0 <= x <= hi:
                    raise ConfigError(
                        f"{name}[{k}] must be in [0, {hi:g}] for color_space {self.color_space!r}, got {x:g}"
                    )
        # Only the hue may wrap (lower > upper); every other channel needs lower <= upper.
        for k in range(3):
            wraps = self.color_space == "hsv" and k == 0
            if lower[k] > upper[k] and not wraps:
                raise ConfigError(f"lower[{k}] must be <= upper[{k}], got {lower[k]:g} > {upper[k]:g}")
        if self.crop is not None:
            c = tuple(self.crop)
            if len(c) != 4 or not all(isinstance(x, (int, np.integer)) for x in c):
                raise ConfigError(f"crop must be (top, left, bottom, right) integers or None, got {self.crop!r}")
            top, left, bottom, right = c
            if not (0 <= top < bottom and 0 <= left < right):
                raise ConfigError(f"crop must satisfy 0 <= top < bottom and 0 <= left < right, got {self.crop!r}")
            object.__setattr__(self, "crop", tuple(int(x) for x in c))
        for name in ("open_size", "close_size"):
            k = getattr(self, name)
            if not isinstance(k, (int, np.integer)) or isinstance(k, bool) or k < 1 or k % 2 == 0:
                raise ConfigError(f"{name} must be an odd integer >= 1, got {k!r}")
        if self.resize not in RESIZE_MODES:
            raise ConfigError(f"resize must be one of {RESIZE_MODES}, got {self.resize!r}")
        if not 0.0 < self.area_threshold <= 1.0:
            raise ConfigError(f"area_threshold must be in (0, 1], got {self.area_threshold!r}")
        for name in ("flip_horizontal", "flip_vertical"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ConfigError(f"{name} must be a bool, got {getattr(self, name)!r}")

    def to_mask(self, rgb: np.ndarray) -> np.ndarray:
        """bool (64, 64) object mask from an RGB frame (H, W, 3) uint8."""
        if not isinstance(rgb, np.ndarray):
            raise ConfigError(f"rgb must be a numpy array (H, W, 3) uint8, got {type(rgb).__name__}")
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] < 1 or rgb.shape[1] < 1:
            raise ConfigError(f"rgb must have shape (H, W, 3), got {rgb.shape}")
        if rgb.dtype != np.uint8:
            raise ConfigError(f"rgb must have dtype uint8, got {rgb.dtype}")
        img = rgb
        if self.crop is not None:
            top, left, bottom, right = self.crop
            h, w = rgb.shape[:2]
            if bottom > h or right > w:
                raise ConfigError(f"crop {self.crop} lies outside the {h}x{w} image (bottom <= {h}, right <= {w})")
            img = img[top:bottom, left:right]
        if self.flip_vertical:
            img = img[::-1]
        if self.flip_horizontal:
            img = img[:, ::-1]
        mask = self.threshold(img)
        if self.open_size > 1:
            mask = dilate(erode(mask, self.open_size), self.open_size)
        if self.close_size > 1:
            mask = erode(dilate(mask, self.close_size), self.close_size)
        if self.resize == "nearest":
            return resize_nearest(mask, OUT)
        return resize_area(mask, OUT, self.area_threshold)

    def threshold(self, rgb: np.ndarray) -> np.ndarray:
        """bool (H, W): every channel within [lower, upper] in `color_space` (hue may wrap)."""
        x = rgb.astype(np.float64) if self.color_space == "rgb" else rgb_to_hsv(rgb)
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        inside = (x >= lo) & (x <= hi)
        if self.color_space == "hsv" and lo[0] > hi[0]:
            inside[..., 0] = (x[..., 0] >= lo[0]) | (x[..., 0] <= hi[0])
        return inside.all(axis=-1)


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 RGB -> float HSV: hue in degrees [0, 360), saturation and value in [0, 1]."""
    x = rgb.astype(np.float64) / 255.0
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    v = x.max(axis=-1)
    c = v - x.min(axis=-1)
    safe_c = np.where(c > 0, c, 1.0)
    h = np.where(v == r, (g - b) / safe_c, np.where(v == g, 2.0 + (b - r) / safe_c, 4.0 + (r - g) / safe_c))
    h = np.where(c > 0, (h * 60.0) % 360.0, 0.0)
    s = np.where(v > 0, c / np.where(v > 0, v, 1.0), 0.0)
    return np.stack([h, s, v], axis=-1)


def _window(mask: np.ndarray, k: int, pad_value: bool, reduce) -> np.ndarray:
    # A square kernel is separable: reduce over k rows, then over k columns.
    r = k // 2
    out = mask
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        p = np.pad(out, pad, constant_values=pad_value)
        win = np.lib.stride_tricks.sliding_window_view(p, k, axis=axis)
        out = reduce(win, axis=-1)
    return out


def erode(mask: np.ndarray, k: int) -> np.ndarray:
    """Binary erosion with a k x k square (outside the image counts as object)."""
    return _window(np.asarray(mask, bool), k, True, np.all)


def dilate(mask: np.ndarray, k: int) -> np.ndarray:
    """Binary dilation with a k x k square (outside the image counts as background)."""
    return _window(np.asarray(mask, bool), k, False, np.any)


def _area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in): fraction of output cell i's footprint covered by input pixel j."""
    edges_out = np.arange(n_out + 1) * (n_in / n_out)
    lo = np.maximum(edges_out[:-1, None], np.arange(n_in)[None, :])
    hi = np.minimum(edges_out[1:, None], np.arange(n_in)[None, :] + 1)
    return np.clip(hi - lo, 0.0, None) * (n_out / n_in)


def resize_area(mask: np.ndarray, n: int = OUT, threshold: float = 0.5) -> np.ndarray:
    """(H, W) bool -> (n, n) bool: set where the object covers >= `threshold` of the output pixel."""
    h, w = mask.shape
    frac = _area_weights(h, n) @ mask.astype(np.float64) @ _area_weights(w, n).T
    return frac >= threshold - 1e-9  # tolerance for the float sums of exact fractions


def resize_nearest(mask: np.ndarray, n: int = OUT) -> np.ndarray:
    """(H, W) bool -> (n, n) bool: the source pixel under each output pixel's centre."""
    h, w = mask.shape
    rows = np.minimum(((np.arange(n) + 0.5) * h / n).astype(int), h - 1)
    cols = np.minimum(((np.arange(n) + 0.5) * w / n).astype(int), w - 1)
    return mask[np.ix_(rows, cols)]
