"""RAPID-style reactive background traffic (paper 004): a few-step diffusion model of each background agent's
next-step acceleration, with cached map context and physics (social-force) guidance at sampling time.

`features` (inputs), `network` (map / agent encoders, denoiser), `sampler` (DDIM, eq. 7 guidance), `data`
(training samples from logs), `train` (fit, model file), `background` (`RapidBackground`, the env controller).
"""

from seal.models.rapid.background import RapidBackground, load_rapid
from seal.models.rapid.sampler import Guidance

__all__ = ["Guidance", "RapidBackground", "load_rapid"]
