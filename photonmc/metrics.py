"""Image error metrics shared by tests, `converge` and the tools.

relMSE is mean(|d|^2 / (ref^2 + eps)) per channel; note the square is taken once (one public
implementation squares it twice). `relmse_epsilon` ties eps to the reference (docs/convergence.md,
"Relative error").
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


RELMSE_FLOOR = 0.1     # eps = (RELMSE_FLOOR * mean luminance of the reference)^2


def relmse_epsilon(ref: np.ndarray) -> float:
    """eps of relMSE for this reference: (0.1 * its mean luminance)^2.

    The customary eps = 0.01 (e.g. Rousselle et al. 2011) presumes an image of mean ~1: on
    an image whose pixels are mostly below 0.1 it turns relMSE into MSE / 0.01. Scaling it
    with the reference keeps that meaning at any exposure (relMSE no longer changes when the
    scene's radiance is scaled) and counts a pixel's error relative to its own value down to
    a tenth of the image's mean, relative to that floor below it."""
    m = mean_luminance(ref)
    return float((RELMSE_FLOOR * m) ** 2) if m > 0 else 1e-2


def relmse(img: np.ndarray, ref: np.ndarray, eps: float) -> float:
    d = np.asarray(img, np.float64) - np.asarray(ref, np.float64)
    return float(np.mean(d * d / (np.asarray(ref, np.float64) ** 2 + eps)))


def relmse_spread(img: np.ndarray, ref: np.ndarray, eps: float) -> float:
    """Coefficient of variation (std / mean over pixels) of one render's per-pixel relMSE.
    Its floor is about sqrt(2) even when every pixel has the same expected error; see
    `relmse_spread_over_seeds` for the spread of the expectations."""
    per_pixel = per_pixel_relmse(img, ref, eps)
    m = per_pixel.mean()
    return float(per_pixel.std() / m) if m > 0 else 0.0


def per_pixel_relmse(img: np.ndarray, ref: np.ndarray, eps: float) -> np.ndarray:
    d = np.asarray(img, np.float64) - np.asarray(ref, np.float64)
    return np.mean(d * d / (np.asarray(ref, np.float64) ** 2 + eps), axis=-1)


def relmse_spread_over_seeds(images, ref: np.ndarray, eps: float) -> float | None:
    """Spread (std / mean over pixels) of each pixel's *expected* relMSE, from renders with
    independent seeds.

    One render's per-pixel squared error is its expectation times a chi-square-like factor,
    whose own spread (about sqrt(2) per pixel) swamps the spread of the expectations that
    Gruson et al.'s spatial target is meant to flatten. With K seeds, the per-pixel mean over
    seeds m(p) has var_p(m) = var_p(E e) + mean_p(var(e)) / K; the second term is estimated
    from the seeds' sample variance and subtracted. None for fewer than 2 images."""
    if len(images) < 2:
        return None
    e = np.stack([per_pixel_relmse(img, ref, eps) for img in images])        # (K, H, W)
    k = e.shape[0]
    m = e.mean(axis=0)
    noise = e.var(axis=0, ddof=1).mean() / k
    mean = m.mean()
    if mean <= 0:
        return 0.0
    return float(np.sqrt(max(0.0, m.var() - noise)) / mean)


def noise_and_systematic_error(images, ref: np.ndarray, reference_noise_mse: float = 0.0):
    """(noise, systematic): one render's RMSE split into what independent seeds average away
    and what they share, from renders with independent seeds (None for fewer than 2).

    noise^2 = the per-pixel variance over seeds (ddof 1), averaged over pixels and channels:
    a single render's expected squared error from its randomness. systematic^2 = the squared
    error of the seeds' mean image, less what its own noise (noise^2 / K) and the reference's
    (reference_noise_mse, from its header) add, clamped at 0: the error that averaging more renders
    of this budget would not remove (photon mapping's radius bias at the radii reached, a
    start-up bias, a modelling difference from the reference). With `rmse` both are over all channels,
    so noise^2 + systematic^2 + reference_noise_mse ~ RMSE^2 (docs/convergence.md)."""
    if len(images) < 2:
        return None
    x = np.stack([np.asarray(img, np.float64) for img in images])
    k = x.shape[0]
    noise_sq = float(x.var(axis=0, ddof=1).mean())
    mean_sq = float(np.mean((x.mean(axis=0) - np.asarray(ref, np.float64)) ** 2))
    return float(np.sqrt(noise_sq)), float(np.sqrt(max(0.0, mean_sq - noise_sq / k - reference_noise_mse)))


def mean_luminance_bias(img: np.ndarray, ref: np.ndarray) -> float:
    """Relative difference of mean luminance (img - ref) / ref."""
    r = mean_luminance(ref)
    return (mean_luminance(img) - r) / r


def downsample(img: np.ndarray, factor: int) -> np.ndarray:
    h, w = img.shape[:2]
    h2, w2 = h // factor, w // factor
    x = np.asarray(img, np.float64)[: h2 * factor, : w2 * factor]
    return x.reshape(h2, factor, w2, factor, *img.shape[2:]).mean(axis=(1, 3))
