"""The fluoroscopic detector: quantum noise and blur of one pulsed-fluoroscopy frame.

The clean `fluoro` image (`cathsim_dmc.sim.raster`) is the X-ray transmission an ideal
detector would average over each output pixel. A real frame counts a finite number of
X-ray quanta, and its detector and focal spot blur it. Both are set from published
image-quality figures (docs/observations.md#fluoro):

* the dose: the air kerma at the detector per frame, `dose_ngy` (3.9 uR = 34 nGy per frame
  with an RQA 5 beam in Friedman & Cunningham's fluoroscopic DQE measurement);
* the quanta per air kerma of that beam (IEC 62220-1-1, RQA 5: 30,174 per mm^2 per uGy);
* the detective quantum efficiency at that dose (0.64 at zero frequency, same measurement),
  which turns the incident quanta into the noise-equivalent quanta an ideal counter would see;
* the magnification of the vessel onto the detector (a C-arm with 1 m from focus to
  detector and the patient's back 0.5 m from it: `MAGNIFICATION`), so that a pixel of the
  image (sized at the vessel, as the rest of the simulator measures) collects the quanta
  of a `MAGNIFICATION` times wider square of the detector;
* the blur: a Gaussian point-spread function of `blur_mm` at the vessel.

The automatic dose-rate control of a fluoroscope holds the detector dose behind the
patient: `dose_ngy` is that of the background (the patient without contrast), and a pixel
transmitting a fraction t of the background counts t times its quanta (Poisson).
"""

from __future__ import annotations

import cv2
import numpy as np

# IEC 62220-1-1:2015, Table 2: SNR_in^2 per air kerma of the RQA 5 beam (70 kV, 21 mm Al).
RQA5_QUANTA_PER_MM2_PER_UGY = 30174.0
# Friedman & Cunningham, Med. Phys. 37 (2010): zero-frequency DQE of a fluoroscopic
# system with an RQA 5 beam at 3.9 uR (34 nGy) per frame.
FLUORO_DQE = 0.64
FLUORO_DOSE_NGY = 34.0
# Focus-detector distance 1 m, the patient's entrance surface 0.5 m from the detector
# (typical C-arm geometry in body angiography), the aorta about 8 cm inside the patient.
MAGNIFICATION = 1.0 / (1.0 - 0.42)


# Above this many quanta in every pixel a frame draws the Poisson law's normal limit (same
# mean and variance; its skewness, 1/sqrt(quanta), is below 0.1).
NORMAL_QUANTA = 100.0


def background_quanta(dose_ngy: float, pixel_m: float) -> float:
    """Noise-equivalent quanta that one image pixel (`pixel_m` wide at the vessel)
    collects from the background at a detector dose of `dose_ngy` per frame."""
    pixel_mm = 1e3 * pixel_m * MAGNIFICATION
    return RQA5_QUANTA_PER_MM2_PER_UGY * 1e-3 * dose_ngy * FLUORO_DQE * pixel_mm**2


def fluoroscopy_frame(
    image: np.ndarray, random_state, quanta: float, blur_px: float, background_level: float
) -> np.ndarray:
    """`image` (grey levels, any shape, `background_level` the background's) as one detector
    frame: blurred by a Gaussian of `blur_px` pixels, then each pixel's quanta drawn from a
    Poisson law whose mean is `quanta` times its level over the background's; uint8."""
    frame = image.astype(np.float32)
    if blur_px > 0:
        squeezed = frame.reshape(frame.shape[0], frame.shape[1])
        frame = cv2.GaussianBlur(squeezed, (0, 0), sigmaX=float(blur_px), borderType=cv2.BORDER_REPLICATE).reshape(
            image.shape
        )
    if quanta > 0:
        mean = np.maximum(frame, 0.0) * (quanta / background_level)
        if mean.min() >= NORMAL_QUANTA:  # the Poisson law's normal limit, at half its cost
            counts = mean + np.sqrt(mean) * random_state.standard_normal(mean.shape)
        else:
            counts = random_state.poisson(mean)
        frame = counts * (background_level / quanta)
    return np.round(frame).clip(0, 255).astype(np.uint8)
