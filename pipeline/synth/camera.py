"""The phone camera's sensor: exposure and white-balance gains, noise, clipping, sRGB, 8 bits.

The work is done by the ``sensor`` OpenCL kernel (:mod:`relight.kernels.sensor`); noise is
counter-based, keyed by the capture seed and the frame index, so a frame can be re-made alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from relight.kernels.sensor import SensorKernel, frame_key


@dataclass
class Sensor:
    """Poisson-Gaussian sensor noise on linear values (0-1 full scale).

    read_noise : standard deviation of the signal-independent part.
    shot_gain : variance added per unit of signal (photon noise); at 0.5 the default gives
    a standard deviation of 0.01, an SNR of 50.
    """

    read_noise: float = 0.003
    shot_gain: float = 2.0e-4
    _kernels: dict = field(default_factory=dict, repr=False)

    def scaled(self, amount: float) -> Sensor:
        """The same sensor with noise standard deviations times ``amount``."""
        return Sensor(self.read_noise * amount, self.shot_gain * amount * amount)

    def expose(self, linear: np.ndarray, gain: float, white_balance: np.ndarray,
               noise_key: tuple[int, int] | None) -> np.ndarray:
        """Linear scene values (H, W, 3) -> uint8 sRGB frame.

        noise_key : (seed, frame) for the counter-based noise, or None for a noise-free frame.
        """
        shape = linear.shape[:2]
        kern = self._kernels.get(shape)
        if kern is None:
            kern = self._kernels[shape] = SensorKernel(shape)
        noisy = noise_key is not None and (self.read_noise > 0 or self.shot_gain > 0)
        key = frame_key(*noise_key) if noisy else None
        gains = float(gain) * np.asarray(white_balance, dtype=np.float64)
        return kern.expose(linear, gains, self.read_noise, self.shot_gain, key)
