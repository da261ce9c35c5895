"""The camera's imaging chain after the optics, shared by the renderers: the light of a frame
(the scene's gain and white balance over time), sensor noise (read noise plus shot noise, drawn
from a bank of normal noise shifted per frame), chroma subsampling and the JPEG round trip.
Each renderer runs the steps in its camera's order, with its own optics and sensor between
them (omni_renderer: blur, a 3 x 3 colour transform, a tone curve; perspective_renderer:
chromatic aberration, corner blur, motion blur, a Bayer mosaic, vignetting).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..common.errors import FieldlocError

CHROMA_METHODS = ("box", "decimate")


def frame_light(scene, frame: int) -> tuple[float, np.ndarray]:
    """(gain, white balance (3,) BGR multipliers) of ``frame`` in ``scene``'s lighting (the
    last frame's beyond its end); neutral for a scene without lighting."""
    n = len(scene.gain) if scene.gain is not None else 0
    i = min(int(frame), n - 1) if n else 0
    gain = float(scene.gain[i]) if scene.gain is not None else 1.0
    wb = (np.asarray(scene.white_balance[i], float) if scene.white_balance is not None
          else np.ones(3))
    return gain, wb


def noise_window(bank: np.ndarray, rng: np.random.Generator, oy: int, ox: int, h: int,
                 w: int) -> np.ndarray:
    """The (h, w) window of the noise ``bank`` at (oy, ox), upside down half of the time (one
    draw of ``rng``): a frame's noise without drawing a new field per frame."""
    noise = bank[oy: oy + h, ox: ox + w]
    if rng.random() < 0.5:
        noise = noise[::-1]
    return noise


def add_sensor_noise(img: np.ndarray, noise: np.ndarray, shot: float, read: float) -> None:
    """Add sensor noise to the float32 levels ``img`` in place: sigma = shot * sqrt(level) +
    read, times the unit normal ``noise`` (broadcast to ``img``)."""
    sigma = np.sqrt(np.maximum(img, 0))
    sigma *= np.float32(shot)
    sigma += np.float32(read)
    sigma *= noise
    img += sigma


def chroma_subsample(img: np.ndarray, k: int, method: str) -> np.ndarray:
    """The BGR uint8 ``img`` with its chroma shared by ``k`` neighbouring pixels of a row (the
    luma kept): ``box``, a box of k over YUV (as in YUV 4:1:1 cameras), or ``decimate``, Cr and
    Cb kept at 1 / k of the columns (area) and widened again (nearest), as 4:2:2 sensors do."""
    if k <= 1:
        return img
    if method == "box":
        yuv = cv2.cvtColor(img, cv2.COLOR_BGR2YUV)
        y = cv2.split(yuv)[0]
        _, u, v = cv2.split(cv2.blur(yuv, (k, 1)))
        return cv2.cvtColor(cv2.merge([y, u, v]), cv2.COLOR_YUV2BGR)
    if method == "decimate":
        h, w = img.shape[:2]
        y_, cr, cb = cv2.split(cv2.cvtColor(img, cv2.COLOR_BGR2YCrCb))
        cr, cb = (cv2.resize(cv2.resize(c, (w // k, h), interpolation=cv2.INTER_AREA),
                             (w, h), interpolation=cv2.INTER_NEAREST) for c in (cr, cb))
        return cv2.cvtColor(cv2.merge([y_, cr, cb]), cv2.COLOR_YCrCb2BGR)
    raise FieldlocError(f"unknown chroma subsampling '{method}' ({', '.join(CHROMA_METHODS)})")


def jpeg_round_trip(img: np.ndarray, quality: int) -> np.ndarray:
    """``img`` as it comes back from a JPEG of ``quality`` (0: unchanged)."""
    if quality <= 0:
        return img
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise FieldlocError("JPEG encoding of a rendered frame failed")
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)
