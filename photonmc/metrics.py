"""Image error metrics shared by tests, `converge` and the tools.

relMSE is mean(|d|^2 / (ref^2 + eps)) per channel, with eps stated by the caller; note the
square is taken once (one public implementation squares it twice, see algorithms.md §11).
"""
import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])


def luminance(img: np.ndarray) -> np.ndarray:
    return np.asarray(img, np.float64)[..., :3] @ LUMA


def mean_luminance(img: np.ndarray) -> float:
    return float(luminance(img).mean())


def rmse(img: np.ndarray, ref: np.ndarray) -> float:
    d = np.asarray(img, np.float64) - np.asarray(ref, np.float64)
    return float(np.sqrt(np.mean(d * d)))


def relmse(img: np.ndarray, ref: np.ndarray, eps: float = 1e-2) -> float:
    d = np.asarray(img, np.float64) - np.asarray(ref, np.float64)
    return float(np.mean(d * d / (np.asarray(ref, np.float64) ** 2 + eps)))


def relmse_spread(img: np.ndarray, ref: np.ndarray, eps: float = 1e-2) -> float:
    """Coefficient of variation (std / mean over pixels) of per-pixel relMSE: 0 when every
    pixel has the same relative error (the spatial target's goal, Gruson et al. 2016)."""
    d = np.asarray(img, np.float64) - np.asarray(ref, np.float64)
    per_pixel = np.mean(d * d / (np.asarray(ref, np.float64) ** 2 + eps), axis=-1)
    m = per_pixel.mean()
    return float(per_pixel.std() / m) if m > 0 else 0.0


def mean_luminance_bias(img: np.ndarray, ref: np.ndarray) -> float:
    """Relative difference of mean luminance (img - ref) / ref."""
    r = mean_luminance(ref)
    return (mean_luminance(img) - r) / r


def downsample(img: np.ndarray, factor: int) -> np.ndarray:
    h, w = img.shape[:2]
    h2, w2 = h // factor, w // factor
    x = np.asarray(img, np.float64)[: h2 * factor, : w2 * factor]
    return x.reshape(h2, factor, w2, factor, *img.shape[2:]).mean(axis=(1, 3))
