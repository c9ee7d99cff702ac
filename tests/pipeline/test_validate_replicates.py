"""validate's z_within_fraction against a reference whose variance image is a replicate estimate
(the Sobol sampler's R = 16 replicates, 15 degrees of freedom): a model equal to the truth scores
about 1 - alpha only with Student-t thresholds. Synthetic images, fixed seed, no rendering."""
from __future__ import annotations

import numpy as np

from pipeline.stages.validate import ValidateConfig, compare_view, z_critical

R = 16


def _replicate_reference(truth: np.ndarray, sigma: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A reference as render.film.Film.variance makes it: the mean of R normal replicate means
    (each of standard deviation sigma) and the variance of that mean from their spread."""
    reps = truth[None] + sigma * np.random.default_rng(seed).standard_normal((R, *truth.shape))
    mean = reps.mean(0)
    var = reps.var(0, ddof=1) / R
    return mean.astype(np.float32), var.astype(np.float32)


def test_a_perfect_model_scores_one_minus_alpha_against_a_replicate_reference():
    """100 x 100 x 3 pixel channels (truth 0.5, sigma 0.01: z_within_fraction's sd ~ 5.7e-4 at
    alpha 0.01): with R - 1 = 15 degrees of freedom the fraction is within 5 sd of 0.99; with the
    normal threshold it would be P(|t_15| <= 2.576) = 0.979 (checked too, so the test can fail)."""
    truth = np.full((100, 100, 3), 0.5)
    ref, var = _replicate_reference(truth, 0.01, seed=3)
    cfg = ValidateConfig(flip=False, sigma_floor=1e-9)
    alpha, n = cfg.alpha, truth.size
    sd = np.sqrt(alpha * (1 - alpha) / n)
    with_t = compare_view(truth.astype(np.float32), ref.astype(np.float64), var, cfg, var_dof=R - 1)
    normal = compare_view(truth.astype(np.float32), ref.astype(np.float64), var, cfg)
    assert abs(with_t["z_within_fraction"] - (1 - alpha)) < 5 * sd, with_t["z_within_fraction"]
    assert abs(normal["z_within_fraction"] - 0.979) < 5 * np.sqrt(0.979 * 0.021 / n), normal["z_within_fraction"]
    assert z_critical(alpha, R - 1) > z_critical(alpha) > 2.57
