"""A per-cell uncertainty: the generator's second output channel, a log-variance.

With ``model.uncertainty`` the generator returns ``(B, 2, H, W)``: channel 0 the height (m),
channel 1 ``log sigma^2`` of that height's error (m^2). The log-variance is trained by the
Gaussian negative log-likelihood of the *detached* error,

    nll = 0.5 * (|height - target|^2 / sigma^2 + log sigma^2),

whose minimum over ``sigma^2`` is the expected squared error at that cell. The height itself is
learnt by the same L1 (and GAN) terms as without the head: the error is detached, so the NLL
cannot trade accuracy for a larger sigma (the failure mode of a joint NLL; Seitzer et al., 2022,
"On the pitfalls of heteroscedastic uncertainty estimation").
"""

from __future__ import annotations

import torch

#: log sigma^2 is clamped to this range: sigma from 0.3 mm to 55 m.
LOG_VARIANCE_RANGE = (-16.0, 8.0)


def split_output(output: torch.Tensor, uncertainty: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
    """A generator's ``(B, C, H, W)`` output -> ``(height (B, 1, H, W), log-variance or None)``."""
    if not uncertainty:
        return output[:, :1], None
    return output[:, :1], output[:, 1:2].clamp(*LOG_VARIANCE_RANGE)


def gaussian_nll(log_variance: torch.Tensor, error: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """mean(weight * 0.5 * (error^2 exp(-log_variance) + log_variance)), the error detached."""
    nll = 0.5 * (error.detach().square() * torch.exp(-log_variance) + log_variance)
    if weight is not None:
        nll = nll * weight
    return nll.mean()


def standard_deviation(log_variance: torch.Tensor) -> torch.Tensor:
    """sigma (m) from log sigma^2."""
    return torch.exp(0.5 * log_variance)
