"""Radiance-field models, pure PyTorch: the faithful NeRF and a fast factored-grid model.

Every model lives in an axis-aligned box [lo, hi] (world units) and renders rays with the shared
quadrature :func:`recon.nerf.volume.composite`; outside the box there is only the background colour.
Densities are defined per unit of the box's normalised coordinates and converted to world units
(sigma_world = sigma_unit * 2 / side for [-1, 1] coordinates), so the same settings fit any scene
scale.

* :class:`VanillaNeRF` - Mildenhall et al. (2020): positional encoding (10 frequencies for
  position, 4 for direction), an 8x256 ReLU MLP with the input concatenated again at the fifth
  layer, density from the trunk, colour from a 128-wide head fed the 256 feature and the encoded
  direction; coarse and fine networks, the fine one sampled by inverse CDF of the coarse weights;
  loss on both. Ablations (the paper's Fig. 4): ``use_viewdirs=False`` (no view dependence),
  ``pos_freqs=dir_freqs=0`` (no positional encoding).
* :class:`FastNeRF` - TensoRF-VM (Chen et al. 2022): density and appearance as sums of
  vector-matrix outer products sampled with ``grid_sample``, a small MLP for colour (features +
  spherical-harmonic direction encoding), coarse-to-fine grid upsampling, fixed-step marching that
  skips empty space with an occupancy grid computed *exactly* from the factored density (the max
  over each cell's vertices bounds the trilinear interior), and two-pass early termination: a
  no-grad density pass finds where the transmittance falls below 1e-4, the gradient pass
  evaluates only the samples before that.

Departures from the papers for 2 CPU cores are listed in each config's docstring.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, get_args

import torch
import torch.nn.functional as F
from torch import nn

from .volume import STOP_TRANSMITTANCE, alpha_from_tau, composite, exclusive_transmittance, optical_depth, ray_aabb

from .encoding import SH_DIM, PositionalEncoding, sh_encoding
from .sampling import march_steps, sample_pdf, stratified

__all__ = ["VanillaConfig", "FastConfig", "FineLoss", "FINE_LOSSES", "RenderOut", "VanillaNeRF", "FastNeRF", "MODELS", "make_model"]


@dataclass
class RenderOut:
    """Rendered rays: rgb (R, 3) with background; distance (R,) expected termination distance
    along the ray (0 where nothing absorbed); opacity (R,); aux (list of (R, 3)) further
    predictions that the loss also fits (NeRF's coarse network); n_points: field evaluations."""

    rgb: torch.Tensor
    distance: torch.Tensor
    opacity: torch.Tensor
    aux: list = field(default_factory=list)
    n_points: int = 0


# --------------------------------------------------------------------------- configs

#: the fast model's loss on its pyramid levels (:attr:`FastConfig.fine_loss`)
FineLoss = Literal["display", "tangent"]
FINE_LOSSES: tuple[str, ...] = get_args(FineLoss)


@dataclass(frozen=True)
class VanillaConfig:
    """NeRF as published, except for CPU time: 32 coarse + 64 fine samples per ray (paper 64 + 128;
    our samples span only the scene's box, not a loose near/far range), 1024 rays per batch (paper
    4096), softplus instead of ReLU on the density (a ReLU can start dead), learning rate 5e-4
    decayed exponentially to 5e-5 over the budget (paper: over 500k steps), colour heads starting
    at the training images' mean colour (:meth:`VanillaNeRF.init_colour`; paper: 0.5)."""

    pos_freqs: int = 10
    dir_freqs: int = 4
    use_viewdirs: bool = True
    depth: int = 8
    width: int = 256
    skip: int = 4
    n_coarse: int = 32
    n_fine: int = 64
    lr: float = 5e-4
    lr_final: float = 5e-5
    batch_rays: int = 1024
    #: held-out pixels per view used for the PSNR curve during training (None = whole images)
    curve_pixels: int | None = 1024
    #: render held-out views at the working resolution and repeat pixels up to the capture's size
    render_full_res: bool = False
    background: float = 0.0


@dataclass(frozen=True)
class FastConfig:
    """TensoRF-VM with the paper's learning rates (0.02 grids, 1e-3 MLP, decayed to 0.1x), 16
    density and 27 feature components. For CPUs: 24 appearance components (paper 48) on grids
    upsampled from 128 to 200 per axis (paper 300), an adaptive batch of about
    ``points_per_batch`` = 16384 field evaluations per step (paper ~4096 rays), a step of 1/400 of
    the box side (paper 1/600), density shift -7 (paper -10: the density must appear within tens
    of steps, not thousands), an occupancy grid recomputed exactly from the density from step
    ``occ_start`` on, every ``occ_every`` steps and after each upsampling, and no TV / L1
    regularisers. Why the smaller grids: a step's cost is dominated by grid_sample's backward pass
    and Adam over the whole planes, which scale with resolution^2 x components, not with the batch.
    Measured on the default scene (4 min on 2 idle cores, held-out PSNR at 160x120): the paper's
    48 x 300 grids with 65536 points 28.3 dB (457 steps); 24 x 200 with 65536 points 31.4 dB (860
    steps); 24 x 200 with 16384 points 31.6 dB (1279 steps); 48 x 300 with 16384 points 25.8 dB
    (357 steps). Coarse to fine (session 32; ``pixel_schedule``, ``app_res_final``): on the default
    scene's 10-minute stage (load 4) display PSNR at the capture's 1280x960 25.77 dB against 21.29
    training on the working scale throughout (docs/architecture.md)."""

    res_init: int = 128
    res_final: int = 200
    upsample_at: tuple[float, ...] = (0.08, 0.16, 0.24, 0.32)
    n_comp_sigma: int = 16
    n_comp_app: int = 24
    app_dim: int = 27
    hidden: int = 64
    use_viewdirs: bool = True
    density_shift: float = -7.0
    density_scale: float = 50.0
    steps_per_side: int = 400
    occ_res: int = 64
    occ_tau: float = 1e-4
    occ_start: int = 50
    occ_every: int = 100
    lr_grid: float = 0.02
    lr_net: float = 1e-3
    lr_decay: float = 0.1
    points_per_batch: int = 1 << 14
    min_rays: int = 256
    max_rays: int = 8192
    curve_pixels: int | None = 1024
    #: held-out views rendered at every capture pixel (:meth:`FastNeRF.render_inference`; the
    #: stage falls back to the working scale's pixels repeated only when that render does not fit
    #: its --minutes, recorded in metrics.json)
    render_full_res: bool = True
    #: train on rays through the capture's own pixels (``recon.nerf.data.PixelSampler``) from
    #: progress ``full_res_from`` on; before it (and with False) on the working scale's averages
    train_full_res: bool = False
    full_res_from: float = 0.0
    #: coarse-to-fine training pixels: (progress, factor) pairs, progress ascending; from each
    #: progress on, training rays come from the capture area-averaged by factor (1: its own pixels;
    #: ``recon.nerf.data.PixelSampler``), before the first from the working scale
    pixel_schedule: tuple[tuple[float, int], ...] = ((0.4, 4), (0.6, 2), (0.8, 1))
    #: the appearance grids grow on past ``res_final`` to ``app_res_final`` (0: they stop there with
    #: the density's), geometrically, one step at each progress of ``app_upsample_at`` (after
    #: ``upsample_at``'s): the planes hold the surface textures, the density stays coarser
    app_res_final: int = 400
    app_upsample_at: tuple[float, ...] = (0.5,)
    #: the loss on the pyramid levels (``pixel_schedule``; the working scale keeps ``TrainConfig.loss``):
    #: "display" (MSE of the sRGB encodings) or "tangent" (MSE in linear light weighted by the square
    #: of the sRGB curve's slope at the prediction, held constant: the display error to first
    #: order, dark regions weighed as a viewer sees them, but minimised by the linear mean of what a
    #: pixel's ray cannot resolve, not by its display mean, which is darker: the sRGB curve is
    #: concave). Why: trained on the capture's pixels with "display", the 10-minute stage's 160x120
    #: area average was 0.033 display units darker than the truth on the subject (session 33);
    #: "tangent" 24.16 / 31.67 dB against 24.77 / 29.85 (session 33, 3.5 CPU-minutes, 4 held-out
    #: views, 1280x960 / 160x120 area-averaged display PSNR); the 10-minute stage (load 0.4-1.7)
    #: 26.31 / 34.48 dB, 2649 steps (session 32's quiet: 26.80 / 31.81)
    fine_loss: FineLoss = "tangent"
    background: float = 0.0

    def __post_init__(self) -> None:
        if self.fine_loss not in FINE_LOSSES:
            raise ValueError(f"fine_loss must be one of {', '.join(map(repr, FINE_LOSSES))}, got {self.fine_loss!r}")

    def needs_full_images(self) -> bool:
        """Training reads the capture's own images (``load_data(..., train_full=True)``)."""
        return bool(self.train_full_res or self.pixel_schedule)


# --------------------------------------------------------------------------- shared


class _Boxed(nn.Module):
    def __init__(self, lo, hi):
        super().__init__()
        lo = torch.as_tensor(lo, dtype=torch.float32)
        hi = torch.as_tensor(hi, dtype=torch.float32)
        if lo.shape != (3,) or hi.shape != (3,) or not bool((hi > lo).all()):
            raise ValueError(f"scene box must be (3,) lo < hi, got lo={lo.tolist()} hi={hi.tolist()}")
        self.register_buffer("lo", lo)
        self.register_buffer("hi", hi)

    @property
    def side(self) -> float:
        return float((self.hi - self.lo).max())

    def to_unit(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> box coordinates in [-1, 1]^3."""
        return (x - self.lo) / (self.hi - self.lo) * 2.0 - 1.0


def _mid_deltas(t: torch.Tensor, t0: torch.Tensor, t1: torch.Tensor) -> torch.Tensor:
    """Segment lengths for sorted samples t (R, S): boundaries halfway between samples, the first
    at t0, the last at t1 (R,). Zero-length for rays that miss (t1 <= t0)."""
    mid = 0.5 * (t[:, 1:] + t[:, :-1])
    b = torch.cat([t0[:, None], mid, t1[:, None]], dim=1)
    return (b[:, 1:] - b[:, :-1]).clamp(min=0.0)


# --------------------------------------------------------------------------- vanilla NeRF


class _NerfMLP(nn.Module):
    def __init__(self, cfg: VanillaConfig):
        super().__init__()
        self.pe_x = PositionalEncoding(3, cfg.pos_freqs)
        self.pe_d = PositionalEncoding(3, cfg.dir_freqs)
        self.skip, self.use_viewdirs = cfg.skip, cfg.use_viewdirs
        dims = [self.pe_x.out_dim] + [cfg.width] * cfg.depth
        layers = []
        for i in range(cfg.depth):
            d_in = dims[i] + (self.pe_x.out_dim if i == cfg.skip and i > 0 else 0)
            layers.append(nn.Linear(d_in, cfg.width))
        self.trunk = nn.ModuleList(layers)
        self.sigma = nn.Linear(cfg.width, 1)
        self.feature = nn.Linear(cfg.width, cfg.width)
        d_view = self.pe_d.out_dim if cfg.use_viewdirs else 0
        self.color = nn.Sequential(nn.Linear(cfg.width + d_view, cfg.width // 2), nn.ReLU(),
                                   nn.Linear(cfg.width // 2, 3))

    def forward(self, x_unit: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x_unit (N, 3) in [-1, 1]; d (N, 3) unit directions -> (sigma_unit (N,), rgb (N, 3))."""
        gx = self.pe_x(x_unit)
        h = gx
        for i, layer in enumerate(self.trunk):
            if i == self.skip and i > 0:
                h = torch.cat([h, gx], dim=-1)
            h = F.relu(layer(h))
        sigma = F.softplus(self.sigma(h)[:, 0])
        feat = self.feature(h)
        if self.use_viewdirs:
            feat = torch.cat([feat, self.pe_d(d)], dim=-1)
        return sigma, torch.sigmoid(self.color(feat))


class VanillaNeRF(_Boxed):
    """Coarse + fine NeRF in the box [lo, hi]; see :class:`VanillaConfig`."""

    def __init__(self, cfg: VanillaConfig, lo, hi):
        super().__init__(lo, hi)
        self.cfg = cfg
        self.coarse = _NerfMLP(cfg)
        self.fine = _NerfMLP(cfg)

    def param_groups(self, progress: float) -> list[dict]:
        lr = self.cfg.lr * (self.cfg.lr_final / self.cfg.lr) ** min(progress, 1.0)
        return [{"params": list(self.coarse.parameters()) + list(self.fine.parameters()), "lr": lr, "name": "net"}]

    def learning_rates(self, progress: float) -> dict[str, float]:
        return {"net": self.cfg.lr * (self.cfg.lr_final / self.cfg.lr) ** min(progress, 1.0)}

    def on_progress(self, progress: float, step: int = 0) -> bool:
        return False

    def batch_rays(self) -> int:
        return self.cfg.batch_rays

    def init_colour(self, mean_rgb: torch.Tensor) -> None:
        """Start both colour heads at the training images' mean colour (3,) in (0, 1) instead of
        the paper's 0.5 grey. Why: on a dark capture (the default scene's mean linear radiance is
        0.03) a grey start makes removing all density the fastest way down the loss; the softplus
        density then saturates near zero and never returns (measured: opacity 0 by step 15, held-out
        PSNR frozen at the all-background value)."""
        m = torch.as_tensor(mean_rgb, dtype=torch.float32).clamp(1e-3, 1.0 - 1e-3)
        with torch.no_grad():
            for net in (self.coarse, self.fine):
                net.color[-1].bias.copy_(torch.log(m) - torch.log1p(-m))

    def _eval(self, net, o, d, t, t0, t1):
        R, S = t.shape
        pts = o[:, None, :] + t[..., None] * d[:, None, :]
        sig, rgb = net(self.to_unit(pts.reshape(-1, 3)), d[:, None, :].expand(R, S, 3).reshape(-1, 3))
        delta = _mid_deltas(t, t0, t1)
        return composite(sig.reshape(R, S) * (2.0 / self.side), rgb.reshape(R, S, 3), delta, t,
                         self.cfg.background)

    def render(self, o: torch.Tensor, d: torch.Tensor, training: bool = False,
               generator: torch.Generator | None = None) -> RenderOut:
        """o, d: (R, 3) float32 rays (unit d, world units)."""
        t0, t1 = ray_aabb(o, d, self.lo, self.hi)
        t1 = torch.maximum(t1, t0)
        tc, edges = stratified(t0, t1, self.cfg.n_coarse, training, generator)
        coarse = self._eval(self.coarse, o, d, tc, t0, t1)
        tf = sample_pdf(edges, coarse.weights.detach(), self.cfg.n_fine, training, generator)
        t_all, _ = torch.sort(torch.cat([tc, tf.detach()], dim=1), dim=1)
        fine = self._eval(self.fine, o, d, t_all, t0, t1)
        n = o.shape[0] * (2 * self.cfg.n_coarse + self.cfg.n_fine)
        return RenderOut(fine.rgb, fine.distance, fine.opacity, [coarse.rgb], n)


# --------------------------------------------------------------------------- TensoRF-VM


#: held-out rendering evaluates colour only at samples of larger weight (TensoRF's 1e-4)
COLOUR_MIN_WEIGHT = 1.0e-4
#: held-out renders evaluate colour at samples of larger weight (and each ray's heaviest), the weight
#: of the samples passed over spread over those in proportion: on the default scene's 4-minute model
#: (1280x960 rows) display PSNR 40.5 dB against every sample above COLOUR_MIN_WEIGHT, 1.3 colour
#: evaluations a ray instead of 9.5 (1e-3: 54.2 dB, 4.1; 3e-3: 43.3 dB, 2.1)
COLOUR_INFERENCE_WEIGHT = 1.0e-2
#: empty-space skipping looks this many occupancy cells around a cell (the longest single jump)
SKIP_MAX_CELLS = 8

_PLANE_AXES = ((0, 1), (0, 2), (1, 2))   # plane m spans these coordinates ...
_LINE_AXIS = (2, 1, 0)                    # ... and its vector runs along this one


class _VM(nn.Module):
    """Vector-matrix factorisation: 3 planes (C, res, res) and 3 lines (C, res, 1)."""

    def __init__(self, n_comp: int, res: int, scale: float, generator: torch.Generator):
        super().__init__()
        self.planes = nn.Parameter(scale * torch.randn(3, n_comp, res, res, generator=generator))
        self.lines = nn.Parameter(scale * torch.randn(3, n_comp, res, 1, generator=generator))

    @property
    def res(self) -> int:
        return self.planes.shape[-1]

    def components(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) in [-1, 1] -> (3, C, N) plane * line products per mode and component."""
        pc = torch.stack([x[:, list(a)] for a in _PLANE_AXES])[:, :, None, :]                 # (3, N, 1, 2)
        lc = torch.stack([x[:, a] for a in _LINE_AXIS])
        lc = torch.stack([torch.zeros_like(lc), lc], dim=-1)[:, :, None, :]                  # (3, N, 1, 2)
        p = F.grid_sample(self.planes, pc, mode="bilinear", align_corners=True)[..., 0]     # (3, C, N)
        line = F.grid_sample(self.lines, lc, mode="bilinear", align_corners=True)[..., 0]
        return p * line

    def dense(self) -> torch.Tensor:
        """The summed field on the (res, res, res) vertex grid, indexed [x, y, z]: exact, as the
        trilinear interpolation of these values is the factored field itself."""
        P, L = self.planes, self.lines[..., 0]
        # plane (a, b) is indexed [c, b, a] (grid_sample: W <- first coordinate, H <- second)
        out = torch.einsum("cji,ck->ijk", P[0], L[0])
        out += torch.einsum("cki,cj->ijk", P[1], L[1])
        out += torch.einsum("ckj,ci->ijk", P[2], L[2])
        return out

    def upsample(self, res: int) -> None:
        with torch.no_grad():
            planes = F.interpolate(self.planes.data, size=(res, res), mode="bilinear", align_corners=True)
            lines = F.interpolate(self.lines.data, size=(res, 1), mode="bilinear", align_corners=True)
        self.planes = nn.Parameter(planes.contiguous())
        self.lines = nn.Parameter(lines.contiguous())


class FastNeRF(_Boxed):
    """TensoRF-VM field with occupancy-grid marching in the box [lo, hi]; see :class:`FastConfig`."""

    def __init__(self, cfg: FastConfig, lo, hi, seed: int = 0):
        super().__init__(lo, hi)
        self.cfg = cfg
        g = torch.Generator().manual_seed(seed)
        self.density_vm = _VM(cfg.n_comp_sigma, cfg.res_init, 0.1, g)
        self.app_vm = _VM(cfg.n_comp_app, cfg.res_init, 0.1, g)
        self.basis = nn.Linear(3 * cfg.n_comp_app, cfg.app_dim, bias=False)
        d_in = cfg.app_dim + (SH_DIM if cfg.use_viewdirs else 0)
        self.mlp = nn.Sequential(nn.Linear(d_in, cfg.hidden), nn.ReLU(), nn.Linear(cfg.hidden, cfg.hidden), nn.ReLU(),
                                 nn.Linear(cfg.hidden, 3))
        self.register_buffer("occupancy", torch.ones(cfg.occ_res, cfg.occ_res, cfg.occ_res, dtype=torch.bool))
        self.register_buffer("occ_active", torch.tensor(False))
        self.register_buffer("stage", torch.tensor(0))          # upsamplings done
        self.register_buffer("app_stage", torch.tensor(0))      # appearance-only upsamplings done
        self.register_buffer("occ_updates", torch.tensor(0))    # occupancy recomputations done

    def load_state_dict(self, state, strict: bool = True, assign: bool = False):
        """Accept a checkpoint taken after grid upsampling (resizes the grids first)."""
        for name in ("density_vm", "app_vm"):
            vm = getattr(self, name)
            if f"{name}.planes" in state and state[f"{name}.planes"].shape != vm.planes.shape:
                vm.planes = nn.Parameter(torch.zeros_like(state[f"{name}.planes"]))
                vm.lines = nn.Parameter(torch.zeros_like(state[f"{name}.lines"]))
        if "app_stage" not in state:  # a checkpoint from before appearance-only growth
            state = {**state, "app_stage": torch.tensor(0)}
        return super().load_state_dict(state, strict, assign)

    def param_bytes_final(self) -> int:
        """Bytes of the parameters once every grid has grown to its final resolution."""
        def vm_bytes(c: int, r: int) -> int:
            return 4 * 3 * c * (r * r + r)
        cfg = self.cfg
        grids = vm_bytes(cfg.n_comp_sigma, self._res_at(len(cfg.upsample_at))) + \
            vm_bytes(cfg.n_comp_app, self._app_res_at(len(cfg.app_upsample_at)))
        nets = sum(p.numel() * p.element_size() for m in (self.basis, self.mlp) for p in m.parameters())
        return grids + nets

    # -- field
    @property
    def step(self) -> float:
        return self.side / self.cfg.steps_per_side

    def _sigma(self, feat: torch.Tensor) -> torch.Tensor:
        return F.softplus(feat + self.cfg.density_shift) * (self.cfg.density_scale * 2.0 / self.side)

    def density(self, x_unit: torch.Tensor) -> torch.Tensor:
        """(N, 3) box coordinates in [-1, 1] -> (N,) density in 1 / world unit."""
        return self._sigma(self.density_vm.components(x_unit).sum(dim=(0, 1)))

    def field(self, x_unit: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(N, 3) box coordinates, (N, 3) unit directions -> ((N,) density, (N, 3) colour in (0, 1))."""
        return self.density(x_unit), self.colour(x_unit, sh_encoding(d) if self.cfg.use_viewdirs else None)

    def colour(self, x_unit: torch.Tensor, sh: torch.Tensor | None) -> torch.Tensor:
        """(N, 3) box coordinates and their directions' (N, 16) SH encoding (None without view
        dependence) -> (N, 3) colour in (0, 1)."""
        a = self.app_vm.components(x_unit)                        # (3, C, N)
        feat = self.basis(a.reshape(-1, a.shape[-1]).T)
        if sh is not None:
            feat = torch.cat([feat, sh], dim=-1)
        return torch.sigmoid(self.mlp(feat))

    # -- schedule
    def _target_stage(self, progress: float) -> int:
        return sum(progress >= p for p in self.cfg.upsample_at)

    @staticmethod
    def _log_spaced(start: int, end: int, k: int, n: int) -> int:
        """The k-th of n geometric steps from resolution ``start`` to ``end``."""
        a, b = math.log(start), math.log(end)
        return int(round(math.exp(a + (b - a) * k / n)))

    def _res_at(self, stage: int) -> int:
        n = len(self.cfg.upsample_at)
        if n == 0:
            return self.cfg.res_final
        return self._log_spaced(self.cfg.res_init, self.cfg.res_final, stage, n)

    def _app_res_at(self, app_stage: int) -> int:
        """The appearance grids' resolution after ``app_stage`` appearance-only upsamplings."""
        n = len(self.cfg.app_upsample_at)
        base = self._res_at(len(self.cfg.upsample_at))
        if n == 0 or self.cfg.app_res_final <= 0:
            return base
        return self._log_spaced(base, self.cfg.app_res_final, app_stage, n)

    def on_progress(self, progress: float, step: int = 0) -> bool:
        """Upsample the grids (by progress) and refresh the occupancy (by step) on schedule; True
        when the parameters were replaced (the optimizer must be rebuilt)."""
        changed = False
        target = self._target_stage(progress)
        if target > int(self.stage):
            self.density_vm.upsample(self._res_at(target))
            self.app_vm.upsample(self._res_at(target))
            self.stage.fill_(target)
            changed = True
        if self.cfg.app_res_final > 0 and target == len(self.cfg.upsample_at):
            app_target = sum(progress >= p for p in self.cfg.app_upsample_at)
            if app_target > int(self.app_stage):
                self.app_vm.upsample(self._app_res_at(app_target))
                self.app_stage.fill_(app_target)
                changed = True
        if step >= self.cfg.occ_start:
            due = (step - self.cfg.occ_start) // self.cfg.occ_every + 1
            if due > int(self.occ_updates) or changed:
                self.update_occupancy()
                self.occ_updates.fill_(max(due, int(self.occ_updates)))
        return changed

    @torch.no_grad()
    def update_occupancy(self) -> None:
        """Occupied cells: max over the cell's grid vertices of sigma * step above occ_tau
        (conservative: trilinear interpolation never exceeds its corners), dilated by one cell."""
        sigma = self._sigma(self.density_vm.dense())
        g = self.cfg.occ_res
        occ = F.adaptive_max_pool3d(sigma[None, None], (g, g, g))
        occ = F.max_pool3d(occ, 3, stride=1, padding=1)[0, 0] * self.step > self.cfg.occ_tau
        if bool(occ.any()):  # an untrained (empty) field would cull everything and never learn
            self.occupancy.copy_(occ)
            self.occ_active.fill_(True)

    def _occupied(self, x_unit: torch.Tensor) -> torch.Tensor:
        g = self.cfg.occ_res
        idx = ((x_unit + 1.0) * 0.5 * g).long().clamp(0, g - 1)
        return self.occupancy[idx[:, 0], idx[:, 1], idx[:, 2]]

    def param_groups(self, progress: float) -> list[dict]:
        lr = self.learning_rates(progress)
        return [{"params": list(self.density_vm.parameters()) + list(self.app_vm.parameters()), "lr": lr["grid"],
                 "name": "grid"},
                {"params": list(self.basis.parameters()) + list(self.mlp.parameters()), "lr": lr["net"], "name": "net"}]

    def learning_rates(self, progress: float) -> dict[str, float]:
        f = self.cfg.lr_decay ** min(progress, 1.0)
        return {"grid": self.cfg.lr_grid * f, "net": self.cfg.lr_net * f}

    def batch_rays(self) -> int:
        """Rays per step keeping about points_per_batch evaluations (running mean per ray)."""
        per_ray = getattr(self, "_points_per_ray", float(self.cfg.steps_per_side))
        n = int(self.cfg.points_per_batch / max(per_ray, 1.0))
        return max(self.cfg.min_rays, min(self.cfg.max_rays, n))

    # -- rendering
    @staticmethod
    def _pack(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, int]:
        """Rays (R, S) bool -> (ray index, slot) of each true entry, slots 0.. per ray, and K."""
        rank = torch.cumsum(mask, dim=1) - 1
        r, s = mask.nonzero(as_tuple=True)
        k = int(mask.sum(dim=1).max()) if r.numel() else 0
        return r, rank[r, s], k

    @torch.no_grad()
    def prepare_inference(self, n_points: int | None = None) -> bool:
        """Build the dense density feature grid for the current parameters (their tensors and
        in-place versions); True when it is ready. With ``n_points``, build it only when that many
        lookups repay the build (res^3 multiply-adds per component): a probe of a few rays or the
        curve's pixel subsets keep the factored lookups."""
        vm = self.density_vm
        key = (id(vm.planes), vm.planes._version, id(vm.lines), vm.lines._version)
        if getattr(self, "_dense_key", None) == key:
            return True
        if n_points is not None and n_points < vm.res ** 3 // 8:
            return False
        self._dense_feat = vm.dense().permute(2, 1, 0)[None, None].contiguous()   # (1, 1, z, y, x)
        self._dense_key = key
        return True

    @torch.no_grad()
    def _density_from_grid(self, x_unit: torch.Tensor) -> torch.Tensor:
        """:meth:`density` of (N, 3) box coordinates through the dense (res, res, res) feature grid:
        one trilinear lookup instead of 2 x 3 x n_comp_sigma factored ones, the same field (the
        factored field is trilinear between grid vertices, :meth:`_VM.dense`). The grid is rebuilt
        when the density parameters change (their tensors or in-place versions)."""
        if not self.prepare_inference(x_unit.shape[0]):
            return self.density(x_unit)
        g = x_unit.reshape(1, 1, 1, -1, 3)                        # grid_sample: (x, y, z) -> (W, H, D)
        feat = F.grid_sample(self._dense_feat, g, mode="bilinear", align_corners=True).reshape(-1)
        return self._sigma(feat)

    @torch.no_grad()
    def occupied_box(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The world-space (lo, hi) (3,) of the occupied cells (the whole box before the
        occupancy grid is active or when no cell is occupied)."""
        if not bool(self.occ_active) or not bool(self.occupancy.any()):
            return self.lo, self.hi
        g = self.cfg.occ_res
        idx = self.occupancy.nonzero()
        cell_lo = idx.min(dim=0).values.float() / g
        cell_hi = (idx.max(dim=0).values.float() + 1.0) / g
        size = self.hi - self.lo
        return self.lo + cell_lo * size, self.lo + cell_hi * size

    @torch.no_grad()
    def skip_distance(self) -> torch.Tensor:
        """(g, g, g) int64 over the occupancy grid: 0 for an occupied cell, else the Chebyshev
        distance in cells to the nearest occupied cell, capped at ``SKIP_MAX_CELLS``. A sample in a
        cell at distance D >= 2 may jump (D - 1) cells' width along its ray (any axis moves by at
        most the jump, so every cell passed is within D - 1 of its own: empty). Cached until the
        occupancy grid changes."""
        key = (id(self.occupancy), self.occupancy._version)
        if getattr(self, "_skip_key", None) == key:
            return self._skip_dist
        grown = self.occupancy.float()[None, None]
        dist = torch.zeros(self.occupancy.shape, dtype=torch.int64)
        for _ in range(SKIP_MAX_CELLS):  # after r dilations a cell is covered iff its distance is <= r
            dist += (grown[0, 0] == 0)
            grown = F.max_pool3d(grown, 3, stride=1, padding=1)
        self._skip_dist, self._skip_key = dist, key
        return dist

    @torch.no_grad()
    def march_inputs(self, o: torch.Tensor, d: torch.Tensor) -> tuple:
        """The positional arguments of :func:`recon.nerf.march_kernels.march` for rays o, d (R, 3)
        up to ``min_weight`` (``COLOUR_MIN_WEIGHT``): rays start at the occupied cells' bounding
        box (the sample grid anchored at the scene box's entry), the occupancy grid and its skip
        distances (everything occupied before the grid is active), the dense density features."""
        step = self.step
        t0, t1 = ray_aabb(o, d, self.lo, self.hi)            # the sample grid is anchored at the box entry
        olo, ohi = self.occupied_box()
        s0, s1 = ray_aabb(o, d, olo, ohi)
        s0, s1 = torch.maximum(s0, t0), torch.minimum(s1, t1)
        s1 = torch.where(s1 > s0, s1, torch.zeros_like(s1))  # a ray that misses the occupied box: no sample
        # first step index k with t0 + (k + 0.5) step >= s0: the occupied box's samples, none skipped
        k_first = torch.clamp(torch.floor((s0 - t0) / step - 0.5), min=0).long()
        self.prepare_inference()
        occupied = self.occupancy if bool(self.occ_active) else torch.ones_like(self.occupancy)
        skip = self.skip_distance() if bool(self.occ_active) else torch.zeros(occupied.shape, dtype=torch.int64)
        cell_steps = float(((self.hi - self.lo) / self.cfg.occ_res).min()) / step
        return (o.numpy(), d.numpy(), t0.numpy(), s1.numpy(), k_first.numpy(), step, self.lo.double().numpy(),
                self.hi.double().numpy(), occupied.numpy(), skip.numpy(), cell_steps, self._dense_feat[0, 0].numpy(),
                self.cfg.density_shift, self.cfg.density_scale * 2.0 / self.side, STOP_TRANSMITTANCE, COLOUR_MIN_WEIGHT)

    @torch.no_grad()
    def render_inference(self, o: torch.Tensor, d: torch.Tensor, threads: int | None = None,
                         colour_weight: float = COLOUR_INFERENCE_WEIGHT) -> RenderOut:
        """Held-out rendering (no gradients): the same quadrature and samples as
        ``render(training=False)``, each ray marched by a compiled loop
        (:func:`recon.nerf.march_kernels.march`): rays start at the occupied cells' bounding box,
        jump over empty space by the occupancy grid's distance to the nearest occupied cell
        (:meth:`skip_distance`; only samples of empty cells, which have zero density, are
        jumped), take the density from the dense feature grid (:meth:`prepare_inference`) and
        leave once their transmittance is below ``STOP_TRANSMITTANCE`` (which ``composite``
        weights zero anyway). Colour is evaluated, in one torch batch, only where a sample's
        weight exceeds ``COLOUR_MIN_WEIGHT`` (TensoRF's ray-marching weight threshold: each
        skipped sample changes the colour by at most that weight times its colour); of those, only
        the samples above ``colour_weight`` and each ray's heaviest, their weights scaled to the
        listed ones' sum (``COLOUR_INFERENCE_WEIGHT``; ``COLOUR_MIN_WEIGHT`` keeps them all).
        o, d: (R, 3) float32 rays (unit d, world units); threads: the march's threads (default torch's).
        Why: the training render builds every step of every ray up front and evaluates the
        density behind opaque surfaces; marching in torch segments cost 0.4-0.6 ms a ray on the
        default scene (a 1280x960 view in 8-11 minutes)."""
        from .march_kernels import march

        R = o.shape[0]
        opacity, wsum_t, count, sample_t, sample_w, evals = march(
            *self.march_inputs(o, d), colour_weight=colour_weight, threads=threads or torch.get_num_threads())
        count = torch.from_numpy(count)
        chosen = torch.arange(sample_t.shape[1])[None, :] < count[:, None]
        r_i, s_i = chosen.nonzero(as_tuple=True)
        t_s = torch.from_numpy(sample_t)[r_i, s_i]
        w_s = torch.from_numpy(sample_w)[r_i, s_i]
        rgb = torch.zeros(R, 3)
        if r_i.numel():
            pts = self.to_unit(o[r_i] + t_s[:, None] * d[r_i])
            sh = sh_encoding(d[r_i]) if self.cfg.use_viewdirs else None
            rgb.index_add_(0, r_i, w_s[:, None] * self.colour(pts, sh))
        opacity = torch.from_numpy(opacity).float().clamp(max=1.0)
        wt = torch.from_numpy(wsum_t).float()
        rgb = rgb + (1.0 - opacity)[:, None] * self.cfg.background
        dist_out = torch.where(opacity > 0, wt / opacity.clamp(min=1e-10), torch.zeros_like(wt))
        self.last_march = {"density_lookups": int(evals.sum()), "colour_points": int(r_i.numel()), "rays": R}
        return RenderOut(rgb, dist_out, opacity, [], int(r_i.numel()))

    def render(self, o: torch.Tensor, d: torch.Tensor, training: bool = False,
               generator: torch.Generator | None = None) -> RenderOut:
        """o, d: (R, 3) float32 rays (unit d, world units)."""
        R = o.shape[0]
        t0, t1 = ray_aabb(o, d, self.lo, self.hi)
        step = self.step
        max_steps = int(math.ceil(float((t1 - t0).clamp(min=0).max()) / step)) + 1 if R else 1
        t, valid = march_steps(t0, t1, step, max_steps, training, generator)
        pts = self.to_unit(o[:, None, :] + t[..., None] * d[:, None, :])
        if bool(self.occ_active):
            valid = valid & self._occupied(pts.reshape(-1, 3)).reshape(valid.shape)
        # pass 1 (no grad): densities of occupied samples, packed; find early termination
        r, slot, k = self._pack(valid)
        x = pts[valid]
        tt = t[valid]
        with torch.no_grad():
            sig = torch.zeros(R, max(k, 1))
            if x.numel():
                sig[r, slot] = self.density(x)
            trans = exclusive_transmittance(optical_depth(sig, torch.full_like(sig, step)))
            keep = trans[r, slot] >= STOP_TRANSMITTANCE
        r, x, tt, slot = r[keep], x[keep], tt[keep], slot[keep]
        # pass 2 (grad): the samples that can still be seen, packed again
        mask2 = torch.zeros(R, max(k, 1), dtype=torch.bool)
        mask2[r, slot] = True
        slot2 = (torch.cumsum(mask2, dim=1) - 1)[r, slot]
        k2 = max(int(mask2.sum(dim=1).max()) if r.numel() else 0, 1)
        sigma_p = torch.zeros(R, k2)
        rgb_p = torch.zeros(R, k2, 3)
        t_p = torch.zeros(R, k2)
        delta_p = torch.zeros(R, k2)
        if x.numel():
            # the SH basis depends on the ray only: encoded once per ray (R, 16), then gathered per
            # sample (256 rays, ~290 samples each before the occupancy grid: 300x fewer evaluations)
            sh = sh_encoding(d)[r] if self.cfg.use_viewdirs else None
            s2, c2 = self.density(x), self.colour(x, sh)
            sigma_p = sigma_p.index_put((r, slot2), s2)
            rgb_p = rgb_p.index_put((r, slot2), c2)
            t_p[r, slot2] = tt
            delta_p[r, slot2] = step
        out = composite(sigma_p, rgb_p, delta_p, t_p, self.cfg.background)
        if training:
            n_valid = float(valid.sum())
            self._points_per_ray = 0.9 * getattr(self, "_points_per_ray", n_valid / max(R, 1)) + 0.1 * n_valid / max(R, 1)
        return RenderOut(out.rgb, out.distance, out.opacity, [], int(x.shape[0]))


# --------------------------------------------------------------------------- registry


MODELS: dict[str, tuple[str, object]] = {
    "fast": ("fast", FastConfig()),
    "fast_noview": ("fast", FastConfig(use_viewdirs=False)),
    "vanilla": ("vanilla", VanillaConfig()),
    "vanilla_noview": ("vanilla", VanillaConfig(use_viewdirs=False)),
    "vanilla_nope": ("vanilla", VanillaConfig(pos_freqs=0, dir_freqs=0)),
}


def make_model(name: str, lo, hi, seed: int = 0, config=None) -> nn.Module:
    """A fresh model by registry name (``MODELS``) in the box [lo, hi]; ``config`` overrides the
    registry's config (same kind). Raises ValueError naming the known models."""
    if name not in MODELS:
        raise ValueError(f"unknown NeRF model {name!r}; known: {sorted(MODELS)}")
    kind, cfg = MODELS[name]
    cfg = config or cfg
    torch.manual_seed(seed)
    if kind == "vanilla":
        return VanillaNeRF(cfg, lo, hi)
    return FastNeRF(cfg, lo, hi, seed)
