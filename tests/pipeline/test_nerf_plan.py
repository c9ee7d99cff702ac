"""The nerf stage's time plan for its held-out renders (pipeline/stages/nerf.py): the time reserved
while training is the render the stage then does, and a stage with ``render_full_res`` prices that
render on the capture-size view and does it, recording its wall time (the 1.1x bound on it is
timing: bench/bench_nerf_budget.py checks it).

The planner is checked with fake costs per ray on the default scene's sizes (closed form, no
clock); the stage on the tiny fog-cube capture of tests/recon/nerf_fixtures.py (working scale 16x12,
capture 32x24) with the fast model shrunk, on a 24-second budget.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.stages.nerf import (FULL_RES_SHARE, RENDER_SHARE, NerfStageConfig, RenderReserve, eval_factors,
                                  plan_renders, render_reserve_s, run_nerf)
from render.image_io import read_exr
from tests.recon.nerf_fixtures import FAST_SMALL, SIZE, make_tiny_capture

#: the default scene: 8 held-out views, working scale 160x120, capture 1280x960; a 10-minute budget
VIEWS, SMALL, FULL, BUDGET_S = 8, (160, 120), (1280, 960), 600.0


def test_the_time_reserved_is_the_render_done():
    """For costs per ray from 10 ns to 10 ms: training stops with exactly the reserved time left;
    the render then chosen costs what was reserved (the capture-resolution render when it was
    planned, else the working scale's, never a full-resolution reserve spent on the smaller
    render), the only exception the coarsest scale when nothing fits its share. Both regimes occur,
    and the capture-resolution render is planned exactly when it fits FULL_RES_SHARE."""
    factors = eval_factors(*SMALL)
    rays_at_1, rays_full = VIEWS * SMALL[0] * SMALL[1], VIEWS * FULL[0] * FULL[1]
    view_s = 0.3 * VIEWS
    seen = set()
    for s in np.logspace(-8, -2, 61):
        reserve = render_reserve_s(s, rays_at_1, rays_full, BUDGET_S, view_s, factors)
        available = (reserve - view_s) * (1 + 1e-12)  # (float rounding of the sum and difference)
        k, full = plan_renders(s, rays_at_1, rays_full, available, available, factors)
        done = s * (rays_at_1 / k ** 2 + (rays_full if full else 0)) + view_s
        fits_full = s * (rays_at_1 + rays_full) + view_s <= FULL_RES_SHARE * BUDGET_S
        assert full == fits_full, s
        if full or done <= RENDER_SHARE * BUDGET_S:
            assert done == pytest.approx(reserve, rel=1e-9), (s, k, full, done, reserve)
        else:  # nothing fits the working scale's share: its coarsest, the reserve capped at the share
            assert k == factors[-1] and reserve == pytest.approx(RENDER_SHARE * BUDGET_S)
        if not full:
            assert reserve <= RENDER_SHARE * BUDGET_S + 1e-9
        seen.add((full, k))
    assert (True, 1) in seen and (False, 1) in seen and any(k > 1 for _, k in seen)
    # without render_full_res the capture-resolution render is never planned
    assert plan_renders(1e-9, rays_at_1, 0, 1e9, 1e9, factors) == (1, False)


def test_a_cost_that_falls_late_reserves_no_more_than_is_left():
    """The 4-minute case that left 58 s unused: the cost per ray falls late in training until the
    capture-resolution render (65 s) fits the share (120 s of 240) but no longer the 62 s left.
    The reserve stays the working scale's (training goes on); with 80 s left it is the full render."""
    factors = eval_factors(*SMALL)
    rays_at_1, rays_full = VIEWS * SMALL[0] * SMALL[1], VIEWS * FULL[0] * FULL[1]
    view_s, s = 0.3 * VIEWS, 6.5e-6
    full_cost = s * (rays_at_1 + rays_full) + view_s
    working = s * rays_at_1 + view_s
    assert 62.0 < full_cost < FULL_RES_SHARE * 240.0
    assert render_reserve_s(s, rays_at_1, rays_full, 240.0, view_s, factors) == pytest.approx(full_cost)
    assert render_reserve_s(s, rays_at_1, rays_full, 240.0, view_s, factors, left_s=62.0) == pytest.approx(working)
    assert render_reserve_s(s, rays_at_1, rays_full, 240.0, view_s, factors, left_s=80.0) == pytest.approx(full_cost)


def test_a_capture_resolution_render_once_reserved_stays_reserved():
    """Training has run until the time left is the full render's reserve; a later probe prices it
    5% higher, above what is left: the reserve stays the full render (training stops), where a
    stage that never reserved it keeps the working scale's. When the full render no longer fits
    its share of the budget, the reserve falls back."""
    factors = eval_factors(*SMALL)
    rays_at_1, rays_full = VIEWS * SMALL[0] * SMALL[1], VIEWS * FULL[0] * FULL[1]
    view_s, s = 0.3 * VIEWS, 6.5e-6
    full_cost = s * (rays_at_1 + rays_full) + view_s
    working = s * rays_at_1 + view_s
    held = RenderReserve(rays_at_1, rays_full, 240.0, view_s, factors)
    assert held(s, left_s=200.0) == pytest.approx(full_cost)
    assert held(s, left_s=full_cost) == pytest.approx(full_cost)
    dearer = 1.05 * s * (rays_at_1 + rays_full) + view_s
    assert held(1.05 * s, left_s=full_cost) == pytest.approx(dearer)
    fresh = RenderReserve(rays_at_1, rays_full, 240.0, view_s, factors)
    assert fresh(1.05 * s, left_s=full_cost) == pytest.approx(1.05 * s * rays_at_1 + view_s)
    # beyond FULL_RES_SHARE of the budget: the working scale's, even once held
    big = 1.0 + FULL_RES_SHARE * 240.0 / (s * (rays_at_1 + rays_full))
    assert held(big * s, left_s=1e9) == pytest.approx(min(big * working - (big - 1) * view_s, RENDER_SHARE * 240.0))
    assert not held.full_held


def test_stage_with_render_full_res_prices_and_renders_the_capture_size_views(tmp_path):
    """`render_full_res` on a 24 s budget, training until the deadline: the render cost was probed
    on the capture-size view (32x24, the whole view: fewer pixels than a chunk), the held-out views
    were rendered and scored there, and the stage recorded its wall time with phases that add up to
    it. Whether that wall time stays within 1.1x the budget is timing, checked by
    bench/bench_nerf_budget.py (this run's shape is its default), not here."""
    capture = make_tiny_capture(tmp_path / "capture")
    out = tmp_path / "nerf" / "fast"
    minutes = 0.4
    run_nerf(capture, None, out, NerfStageConfig("fast", minutes, downsample=2,
                                                 overrides=dict(FAST_SMALL, render_full_res=True)), quiet=True)
    m = json.loads((out / "metrics.json").read_text())
    plan, done = m["time"]["planned"], m["time"]["actual"]
    assert plan["render_full_res"] is True and plan["eval_size"] == [SIZE[0] // 2, SIZE[1] // 2]
    assert plan["probe_size"] == list(SIZE) and plan["probe_rays"] == SIZE[0] * SIZE[1] and plan["probes"] >= 1
    assert plan["render_s"] > 0 and plan["render_s_per_ray"] > 0
    assert np.isfinite(m["display_psnr_full_mean"]) and all("display_psnr_full" in r for r in m["views"])
    assert done["stopped_by"] == "deadline" and m["steps"] > 0
    # the wall time is recorded (metrics.json and the manifest) and its phases account for it: the
    # untimed gaps between them (planning, the engine) are a small part of it
    assert m["time"]["budget_s"] == minutes * 60.0
    phases = done["load_s"] + done["train_total_s"] + done["render_s"] + done["write_s"]
    assert 0 < phases <= done["stage_s"] + 0.01 and done["stage_s"] - phases <= 0.05 * done["stage_s"], done
    assert done["train_wall_s"] <= done["train_total_s"] + 0.01
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["metrics"]["stage_s"] == done["stage_s"] and manifest["metrics"]["budget_s"] == minutes * 60.0
    for r in m["views"]:
        assert read_exr(out / "renders" / f"{r['view']}.exr").shape == (SIZE[1], SIZE[0], 3)


def test_the_render_probe_spreads_its_rows_over_the_whole_view(tmp_path, monkeypatch):
    """The probe of whole rows that prices the render takes its rows from the top to the bottom of
    the probe view whatever their number (the first rows of the widest spread were the top of the
    view: the default scene's black background, priced at a fifth of the render's cost). A fixed
    fake cost per ray sizes the probe to about 400 of the view's 768 pixels."""
    import time

    import recon.nerf.train as nt
    from recon.nerf.data import load_data

    data = load_data(make_tiny_capture(tmp_path / "capture"), downsample=2)
    cam = data.test[0].full_camera
    seen = []
    budget_s = 10.0
    fake = nt.PROBE_SHARE * budget_s / 400

    def cost(model, camera, pixels, threads=None):
        seen.append(pixels.clone())
        return fake
    monkeypatch.setattr(nt, "render_cost_per_ray", cost)
    deadline = nt.Deadline(time.perf_counter() + budget_s, lambda s: 0.0, cam)
    nt.train(data, nt.TrainConfig(model="fast", minutes=1, max_steps=1, eval_every_s=1e9, overrides=FAST_SMALL),
             deadline=deadline)
    rows = [p for p in seen if p.shape[0] > nt.PROBE_CALIBRATION_RAYS]
    assert rows, [p.shape for p in seen]
    k = cam.intrinsics
    for p in rows:
        assert p.shape[0] < k.width * k.height
        r = p // k.width
        assert int(r.min()) == 0 and int(r.max()) == k.height - 1, sorted(set(r.tolist()))
