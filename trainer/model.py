"""The GigaDepth branching network: a conv backbone and a classification tree over the projector column.

Conventions. The input is the IR image (B, 1, H, W) at full camera resolution; the network works at
half resolution (the published [model] stride 2; stride 1: at full resolution): output pixel (i, j) is
centred on full-resolution pixel (stride i, stride j) (first conv: odd kernel, that stride, padding
k // 2). The target is the projector column normalised by the projector width,
x in [0, 1], padded to x' = (1 - 2p) x + p; x' * leaves is a position on the leaves of the tree.

Tree. Level l has classes[l] classes per parent (leaves = product). A parent at level l >= 1 also scores
overlaps[l] children of each neighbouring parent, so a pixel routed to the wrong neighbour can still reach
its true child. Level 1 weights are chosen per line, deeper levels per (line, parent), the regressor's
hidden layers per (line, leaf parent) and its output layer per (line, leaf); it gives the offset inside
the leaf. Lines map the output rows onto `lines` weight sets (row * lines // rows). Inference
routes by argmax; training routes by the ground-truth class (teacher forcing) and also trains the
neighbouring parents (CE) and neighbouring leaves (L1), as GigaDepth does. With [model] min_depth set,
every level chooses only among the classes whose projector columns the pixel's image column allows for
depths from min_depth to the rig's max_depth (feasible_positions), in inference and training alike.

Mixed precision (`autocast`, on any device). LCN is computed in float64 and the network's input is
float32; the convs then run in float16/bfloat16, and the indexed layers compute in the dtype of their
input (the backbone's, so the low one), casting the gathered float32 weights to it; their weight
gradients accumulate in float32. These casts are explicit, so the autograd functions need no
torch.amp.custom_fwd (which would tie them to one device type). Logits and offsets leave in the low
precision; the losses and the output column are computed in float32 (in float16 a position on 1280
leaves would be rounded to whole leaves near the end of the tree, in bfloat16 to 8 leaves).
"""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import torch
import torch.distributed as dist
import torch.distributed._functional_collectives as funcol  # autograd-aware collectives
import torch.nn.functional as F
from torch import nn

from dotsim.config_schema import ConfigError
from dotsim.rig.geometry import Rig, depth_to_projector_column
from trainer.config import Config, ModelConfig, output_rows

LOW_PRECISION = {"float16": torch.float16, "bfloat16": torch.bfloat16}
# Leaves by which a class may miss a pixel's feasible range and still be chosen: rounding, and vertical
# jitter moving content a row or two against its line (which matters for a rotated projector only).
FEASIBLE_MARGIN = 0.5


def autocast(device: str | torch.device, precision: str):
    """torch.autocast to `precision` (a LOW_PRECISION name) on `device`'s type, CPU included; any
    other name ("off" in [train].amp, "float32" for inference) runs in float32."""
    dtype = LOW_PRECISION.get(precision)
    return torch.autocast(torch.device(device).type, dtype=dtype, enabled=dtype is not None)


class _IndexedLinearFunction(torch.autograd.Function):
    """Forward: gather each pixel's weights and one batched matmul. Backward written out because
    autograd's backward of index_select scatters a (pixels, out, in) block with scatter_add, measured
    ~100x slower on CPU than index_add_ of the per-pixel outer products (80 vs 0.6 ms, 6000 pixels)."""

    @staticmethod
    def forward(ctx, x, idx, weight, bias, chunk):
        ctx.save_for_backward(x, idx, weight)
        ctx.chunk = chunk
        outs = []
        for s in range(0, x.shape[0], chunk):
            i = idx[s : s + chunk]
            w = weight.index_select(0, i).to(x.dtype)
            outs.append(torch.bmm(w, x[s : s + chunk, :, None])[..., 0] + bias.index_select(0, i).to(x.dtype))
        return torch.cat(outs) if outs else x.new_zeros(0, weight.shape[1])

    @staticmethod
    def backward(ctx, grad):
        x, idx, weight = ctx.saved_tensors
        grad_w = torch.zeros_like(weight)
        grad_b = weight.new_zeros(weight.shape[:2])
        grad_x = torch.empty_like(x)
        for s in range(0, x.shape[0], ctx.chunk):
            i, g, xs = idx[s : s + ctx.chunk], grad[s : s + ctx.chunk], x[s : s + ctx.chunk]
            w = weight.index_select(0, i).to(g.dtype)
            grad_x[s : s + ctx.chunk] = torch.bmm(w.transpose(1, 2), g[:, :, None])[..., 0]
            grad_w.index_add_(0, i, g.float()[:, :, None] * xs.float()[:, None, :])
            grad_b.index_add_(0, i, g.float())
        return grad_x, None, grad_w, grad_b, None


class _GroupedLinearFunction(torch.autograd.Function):
    """The same product with pixels grouped by table: each pixel copied to its place in a zero-padded
    (tables used, most pixels of one table, in) block, one batched matrix-matrix product per table with
    its weights read once. Cheaper than gathering a (pixels, out, in) block when few tables are used.
    The block is filled and read through one flat index per pixel (index_copy_, index_select): two-index
    advanced indexing took most of the time of train_table2's heads (docs/TRAINER.md "Speed")."""

    @staticmethod
    def forward(ctx, x, idx, weight, bias, groups):
        tables, place, count = groups
        xp = _padded(x, tables, place, count)
        w = weight.index_select(0, tables).to(x.dtype)
        y = torch.bmm(xp, w.transpose(1, 2)).view(-1, weight.shape[1]).index_select(0, place)
        ctx.save_for_backward(xp, idx, weight, w)
        ctx.groups = groups
        return y + bias.index_select(0, idx).to(x.dtype)

    @staticmethod
    def backward(ctx, grad):
        xp, idx, weight, w = ctx.saved_tensors
        tables, place, count = ctx.groups
        gp = _padded(grad, tables, place, count)
        grad_x = torch.bmm(gp, w).view(-1, xp.shape[2]).index_select(0, place)
        grad_w = torch.zeros_like(weight).index_copy_(0, tables, torch.bmm(gp.transpose(1, 2).float(),
                                                                            xp.float()))
        grad_b = weight.new_zeros(weight.shape[:2]).index_add_(0, idx, grad.float())
        return grad_x, None, grad_w, grad_b, None


def _padded(rows: torch.Tensor, tables: torch.Tensor, place: torch.Tensor, count: int) -> torch.Tensor:
    """rows (N, f) at their places in a zero-padded (tables used, count, f) block."""
    block = rows.new_zeros(len(tables) * count, rows.shape[1]).index_copy_(0, place, rows)
    return block.view(len(tables), count, -1)


GROUPED_PADDING = 4  # measured: grouping wins while the padded block is a few times the pixels


def plan_groups(idx: torch.Tensor, force: bool = False):
    """How IndexedLinear computes for these indices: (tables used, each pixel's row in the flattened
    padded block (group * largest + rank in its group), largest group size) for the grouped way, or
    False for gathering, chosen by the padding the grouping needs (force: group anyway). Layers with
    the same indices share one plan."""
    if not len(idx):
        return False
    order = torch.argsort(idx, stable=True)
    tables, group, counts = torch.unique_consecutive(idx[order], return_inverse=True, return_counts=True)
    largest = int(counts.max())
    if not force and len(tables) * largest > GROUPED_PADDING * len(idx):
        return False
    starts = torch.cumsum(counts, 0) - counts
    rank = torch.arange(len(idx), device=idx.device) - starts[group]
    place = torch.empty_like(idx).index_copy_(0, order, group * largest + rank)
    return tables, place, largest


class IndexedLinear(nn.Module):
    """y_p = W[idx_p] @ x_p + b[idx_p]: a linear layer whose weights each pixel picks from a table.

    No loop over pixels or classes. Two exact ways (plan_groups chooses): group the pixels by table
    (sort, pad each table's pixels to the largest group, batched matmul) when the padding stays below
    GROUPED_PADDING times the pixels, else gather each pixel's weights and one batched matrix-vector
    product, in chunks of `chunk` pixels to bound the memory of the gathered (chunk, out, in) block.
    Grouping made the tiny network's 1216 x 896 inference 3x faster on CPU (2.8 -> 0.9 s).
    Initialised like nn.Linear (uniform in +-1/sqrt(in)).
    """

    def __init__(self, tables: int, in_features: int, out_features: int, chunk: int = 65536):
        super().__init__()
        bound = 1.0 / math.sqrt(in_features)
        self.weight = nn.Parameter(torch.empty(tables, out_features, in_features).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(tables, out_features).uniform_(-bound, bound))
        self.chunk = chunk

    def forward(self, x: torch.Tensor, idx: torch.Tensor, plan=None) -> torch.Tensor:
        """plan: plan_groups(idx) (or False to gather); None plans here."""
        plan = plan_groups(idx) if plan is None else plan
        if plan is False:
            return _IndexedLinearFunction.apply(x, idx, self.weight, self.bias, self.chunk)
        return _GroupedLinearFunction.apply(x, idx, self.weight, self.bias, plan)


class IndexedMLP(nn.Module):
    """An MLP of IndexedLinear layers with LeakyReLU between; hidden and output layers may use
    different tables (the regressor shares its hidden layer per leaf parent, its output is per leaf)."""

    def __init__(self, dims: list[int], hidden_tables: int, out_tables: int, chunk: int):
        super().__init__()
        self.layers = nn.ModuleList(
            IndexedLinear(hidden_tables if k < len(dims) - 2 else out_tables, dims[k], dims[k + 1], chunk)
            for k in range(len(dims) - 1)
        )

    def forward(self, x: torch.Tensor, hidden_idx: torch.Tensor, out_idx: torch.Tensor) -> torch.Tensor:
        hidden_plan = plan_groups(hidden_idx) if len(self.layers) > 1 else None
        out_plan = hidden_plan if out_idx is hidden_idx else plan_groups(out_idx)
        for k, layer in enumerate(self.layers):
            last = k == len(self.layers) - 1
            x = layer(x, out_idx if last else hidden_idx, out_plan if last else hidden_plan)
            if not last:
                x = F.leaky_relu(x)
        return x


class GlobalBatchNorm2d(nn.BatchNorm2d):
    """BatchNorm2d whose training statistics are those of the global batch when several processes train
    together (trainer/distributed.py): each channel's sum and then its centred sum of squares are summed
    over the ranks (autograd-aware all-reduces), so N ranks x batch B normalise, train and update the
    running statistics as one process with batch N B. torch's SyncBatchNorm would do the same but
    refuses CPU tensors. One process, or eval mode: exactly nn.BatchNorm2d. Same state_dict keys."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and dist.is_initialized() and dist.get_world_size() > 1):
            return super().forward(x)
        x = x.float()  # as autocast runs batch_norm: float16 sums over a batch overflow
        dims, shape = (0, 2, 3), (1, -1, 1, 1)
        local = torch.cat([x.sum(dims), x.new_full((1,), x.numel() // x.shape[1])])
        total = funcol.all_reduce(local, "sum", dist.group.WORLD)
        n = total[-1]
        mean = total[:-1] / n
        centred = x - mean.view(shape)
        var = funcol.all_reduce(centred.square().sum(dims), "sum", dist.group.WORLD) / n
        with torch.no_grad():
            self.num_batches_tracked += 1
            self.running_mean.lerp_(mean, self.momentum)
            self.running_var.lerp_(var * n / (n - 1), self.momentum)  # unbiased, as BatchNorm keeps it
        scale = torch.rsqrt(var + self.eps) * self.weight
        return centred * scale.view(shape) + self.bias.view(shape)


def _conv_bn(cin: int, cout: int, k: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), GlobalBatchNorm2d(cout), nn.LeakyReLU(0.01)]


class ConvBackbone(nn.Sequential):
    """The published plain stack: only the first conv is strided, BatchNorm + LeakyReLU after each."""

    def __init__(self, cfg: ModelConfig):
        layers, cin = [], 2
        for n, (c, k) in enumerate(zip(cfg.backbone_channels, cfg.backbone_kernels, strict=True)):
            layers += _conv_bn(cin, c, k, cfg.stride if n == 0 else 1)
            cin = c
        super().__init__(*layers)


class UNetBackbone(nn.Module):
    """GigaDepth's UNet ablation: a stem (backbone_channels[0], backbone_kernels[0], [model] stride) to
    the output resolution, an encoder of unet_channels (each halving), a decoder with skip connections
    back to it, and a 3x3 conv to backbone_channels[-1]."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        stem = cfg.backbone_channels[0]
        self.stem = nn.Sequential(*_conv_bn(2, stem, cfg.backbone_kernels[0], cfg.stride))
        widths = [stem, *cfg.unet_channels]
        self.down = nn.ModuleList(
            nn.Sequential(*_conv_bn(a, b, 3, 2), *_conv_bn(b, b, 3)) for a, b in pairwise(widths)
        )
        self.up = nn.ModuleList(
            nn.Sequential(*_conv_bn(b + a, a, 3)) for a, b in pairwise(widths)
        )
        self.out = nn.Sequential(*_conv_bn(stem, cfg.backbone_channels[-1], 3))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = [self.stem(x)]
        for down in self.down:
            skips.append(down(skips[-1]))
        x = skips.pop()
        for up in reversed(self.up):
            skip = skips.pop()
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = up(torch.cat([x, skip], 1))
        return self.out(x)


class GigaDepthNet(nn.Module):
    """Backbone + branching regressor. `rows` is the number of output rows of the full camera image
    (ceil(H / stride)); crops pass their first output row so lines keep their identity."""

    def __init__(self, cfg: ModelConfig, rows: int, feasible: torch.Tensor | None = None):
        super().__init__()
        self.cfg, self.rows = cfg, rows
        # [low, high] tree position per (output row, full-resolution column), or None: every
        # class may be chosen (feasible_positions); derived from config and rig, so not saved
        self.register_buffer("feasible", feasible, persistent=False)
        self.backbone = ConvBackbone(cfg) if cfg.backbone == "conv" else UNetBackbone(cfg)
        self.leaves = math.prod(cfg.classes)
        self.classifiers = nn.ModuleList()
        for level, (c, o) in enumerate(zip(cfg.classes, cfg.overlaps, strict=True)):
            tables = cfg.lines * math.prod(cfg.classes[:level])
            dims = [cfg.stage_inputs[level][1], *cfg.classifier_hidden[level], c + 2 * o]
            self.classifiers.append(IndexedMLP(dims, tables, tables, cfg.chunk_pixels))
        leaf_parents = cfg.lines * (self.leaves // cfg.classes[-1])
        dims = [cfg.stage_inputs[-1][1], *cfg.regressor_hidden, 1]
        self.regressor = IndexedMLP(dims, leaf_parents, cfg.lines * self.leaves, cfg.chunk_pixels)

    # ---- shared pieces -------------------------------------------------------------------------
    def inputs(self, ir: torch.Tensor) -> torch.Tensor:
        """[IR, LCN(IR)] (B, 2, H, W): GigaDepth's input; LCN here so train, eval and infer share it."""
        from dotsim.lcn import lcn_torch

        return torch.cat([ir, lcn_torch(ir, self.cfg.lcn_window, self.cfg.lcn_eps)], 1)

    def features(self, ir: torch.Tensor) -> torch.Tensor:
        return self.backbone(self.inputs(ir))

    def pixel_lines(self, row0: torch.Tensor, h: int, w: int) -> torch.Tensor:
        """Line index (B*h*w,) of every output pixel of crops starting at output rows row0."""
        rows = row0.to(torch.long)[:, None] + torch.arange(h, device=row0.device)
        lines = (rows * self.cfg.lines // self.rows).clamp(0, self.cfg.lines - 1)
        return lines[:, :, None].expand(-1, h, w).reshape(-1)

    def pixel_ranges(self, row0: torch.Tensor, x0: torch.Tensor | None, h: int, w: int) -> torch.Tensor:
        """[low, high] tree position (B*h*w, 2) of every output pixel of crops starting at output row
        row0 and full-resolution column x0 (None: 0): output pixel (i, j) sits on full-resolution
        column x0 + stride j."""
        rows = row0.to(torch.long)[:, None] + torch.arange(h, device=row0.device)
        rows = rows.clamp(0, self.rows - 1)
        x0 = torch.zeros_like(row0) if x0 is None else x0
        cols = x0.to(torch.long)[:, None] + self.cfg.stride * torch.arange(w, device=row0.device)
        cols = cols.clamp(0, self.feasible.shape[1] - 1)
        return self.feasible[rows[:, :, None], cols[:, None, :]].reshape(-1, 2)

    def in_range(self, row0: torch.Tensor, x0: torch.Tensor | None, column: torch.Tensor) -> torch.Tensor:
        """bool (B, h, w): the GT column lies in the pixel's feasible range (all True without one):
        pixels nearer than [model] min_depth are left out of the loss, as SGBM leaves out what its
        disparity range does not reach."""
        if self.feasible is None:
            return torch.ones_like(column, dtype=torch.bool)
        b, h, w = column.shape
        low, high = self.pixel_ranges(row0, x0, h, w).unbind(1)
        pos = self.pad_column(column.reshape(-1)) * self.leaves
        return ((pos >= low - FEASIBLE_MARGIN) & (pos <= high + FEASIBLE_MARGIN)).reshape(b, h, w)

    def _feasible_children(self, level: int, first: torch.Tensor, ranges: torch.Tensor | None
                           ) -> torch.Tensor | None:
        """bool (N, c + 2 o): which children a parent may choose at `level`: child k of a parent whose
        first child is the global class `first` (N,) is class first + k - o, feasible where it exists
        and its leaves meet the pixel's range [low, high] (N, 2) (FEASIBLE_MARGIN leaves wider). None
        without a range. A pixel none of whose children is feasible keeps them all."""
        if ranges is None:
            return None
        c, o = self.cfg.classes[level], self.cfg.overlaps[level]
        classes = first[:, None] + torch.arange(c + 2 * o, device=first.device) - o
        span = self.leaves // math.prod(self.cfg.classes[: level + 1])  # leaves per class at this level
        low, high = ranges[:, :1] - FEASIBLE_MARGIN, ranges[:, 1:] + FEASIBLE_MARGIN
        ok = (classes >= 0) & (classes < math.prod(self.cfg.classes[: level + 1]))
        ok &= ((classes + 1) * span > low) & (classes * span <= high)
        return ok | ~ok.any(1, keepdim=True)

    def _stage_input(self, feat: torch.Tensor, stage: int) -> torch.Tensor:
        off, width = self.cfg.stage_inputs[stage]
        x = feat[:, off : off + width]
        return x.permute(0, 2, 3, 1).reshape(-1, width)

    def pad_column(self, column: torch.Tensor) -> torch.Tensor:
        p = self.cfg.column_padding
        return column * (1 - 2 * p) + p

    def unpad_column(self, padded: torch.Tensor) -> torch.Tensor:
        p = self.cfg.column_padding
        return (padded - p) / (1 - 2 * p)

    # ---- inference -----------------------------------------------------------------------------
    def forward(self, ir: torch.Tensor, row0: torch.Tensor | None = None, x0: torch.Tensor | None = None
                ) -> torch.Tensor:
        """Hard-routed prediction: normalised projector column (B, h, w) at half resolution. Crops
        give their first half-resolution row (row0) and full-resolution column (x0)."""
        feat = self.features(ir)
        b, _, h, w = feat.shape
        if row0 is None:
            row0 = torch.zeros(b, dtype=torch.long, device=ir.device)
        line = self.pixel_lines(row0, h, w)
        ranges = None if self.feasible is None else self.pixel_ranges(row0, x0, h, w)
        cls = self.cfg.classes
        g = torch.zeros_like(line)  # global class index at the current level
        for level, (c, o) in enumerate(zip(cls, self.cfg.overlaps, strict=True)):
            parents = math.prod(cls[:level])
            idx = line * parents + g
            logits = self.classifiers[level](self._stage_input(feat, level), idx, idx)
            feasible = self._feasible_children(level, g * c, ranges)
            if feasible is not None:
                logits = logits.masked_fill(~feasible, -math.inf)
            g = (g * c + logits.argmax(1) - o).clamp(0, parents * c - 1)
        hidden_idx = line * (self.leaves // cls[-1]) + g // cls[-1]
        offset = self.regressor(self._stage_input(feat, len(cls)), hidden_idx, line * self.leaves + g)[:, 0]
        padded = (g.float() + offset.float()) / self.leaves
        return self.unpad_column(padded).reshape(b, h, w)

    # ---- training ------------------------------------------------------------------------------
    def loss_terms(
        self, feat: torch.Tensor, row0: torch.Tensor, column: torch.Tensor, valid: torch.Tensor,
        x0: torch.Tensor | None = None,
    ) -> dict[str, list[torch.Tensor] | torch.Tensor]:
        """Per-pixel loss terms over the valid pixels (in valid.flatten().nonzero() order), teacher forced.

        column: GT normalised column (B, h, w); valid: bool (B, h, w), inside the feasible range
        (in_range); x0: the crops' first full-resolution columns. Returns {"ce": [per level (N,)],
        "l1": (N,)}: cross-entropy of the GT parent's and its neighbours' classifiers over their
        feasible children (summed; the neighbours score the true child only where their overlap
        reaches it) and the L1 error of the offsets of the true leaf and `regress_neighbours` leaves on
        each side, in leaf units.
        """
        b, _, h, w = feat.shape
        sel = valid.reshape(-1).nonzero()[:, 0]
        line = self.pixel_lines(row0, h, w)[sel]
        ranges = None if self.feasible is None else self.pixel_ranges(row0, x0, h, w)[sel]
        pos = self.pad_column(column.reshape(-1)[sel]) * self.leaves
        leaf = pos.floor().long().clamp(0, self.leaves - 1)
        cls = self.cfg.classes
        # Each classifier and the regressor run once over all (pixel, neighbour) pairs: one call per
        # level, so autograd builds one dense gradient per weight table instead of one per neighbour.
        ce = []
        for level, (c, o) in enumerate(zip(cls, self.cfg.overlaps, strict=True)):
            parents = math.prod(cls[:level])
            child = leaf // math.prod(cls[level + 1 :])  # global GT class at this level
            span = -(-o // c)
            parent = child // c + torch.arange(-span, span + 1, device=leaf.device)[:, None]  # (2span+1, N)
            target = child - parent * c + o
            ok = (parent >= 0) & (parent < parents) & (target >= 0) & (target < c + 2 * o)
            k = ok.nonzero()[:, 1]
            idx = line[k] * parents + parent[ok]
            x = self._stage_input(feat, level).index_select(0, sel[k])
            logits = self.classifiers[level](x, idx, idx).float()
            feasible = self._feasible_children(level, parent[ok] * c, None if ranges is None else ranges[k])
            if feasible is not None:
                logits = logits.masked_fill(~feasible, -math.inf)
            loss = F.cross_entropy(logits, target[ok], reduction="none")
            ce.append(torch.zeros_like(pos).index_add(0, k, loss))
        r = self.cfg.regress_neighbours
        cand = leaf + torch.arange(-r, r + 1, device=leaf.device)[:, None]  # (2r+1, N) leaves
        ok = (cand >= 0) & (cand < self.leaves)
        k, cand = ok.nonzero()[:, 1], cand[ok]
        hidden_idx = line[k] * (self.leaves // cls[-1]) + cand // cls[-1]
        x = self._stage_input(feat, len(cls)).index_select(0, sel[k])
        offset = self.regressor(x, hidden_idx, line[k] * self.leaves + cand)[:, 0]
        l1 = torch.zeros_like(pos).index_add(0, k, (offset.float() - (pos[k] - cand)).abs())
        return {"ce": ce, "l1": l1}



# The fewest leaves the columns of [model] min_depth .. max_depth must span somewhere in the image: within
# one leaf every level of the tree has at most one feasible class, nothing is left to choose (19.9 m of a
# 20 m rig trained with loss 0); tests/trainer/test_feasible_classes.py trains with 1.34 leaves (3 m).
MIN_FEASIBLE_LEAVES = 1.0


def feasible_positions(cfg: ModelConfig, rig: Rig) -> torch.Tensor | None:
    """[low, high] tree position (x' * leaves) of the projector columns that depths from
    [model] min_depth to the rig's max_depth give, per (output row, full-resolution column) of the
    camera: (ceil(H / stride), W, 2) float32, or None when min_depth is 0 (no restriction). Along a
    camera ray the projector column is monotonic in depth (a ratio of two linear functions of it, with
    no pole in front of the projector), so the ends of the depth range give the ends of the column range;
    a ray that leaves the projector's front keeps every class."""
    if cfg.min_depth <= 0:
        return None
    if cfg.min_depth >= rig.max_depth:
        raise ConfigError(f"[model] min_depth = {cfg.min_depth:g}: not below the rig's max_depth "
                          f"{rig.max_depth:g} m; allowed: 0 (every class) or a depth below max_depth")
    shape = (rig.camera.height, rig.camera.width)
    ends = [depth_to_projector_column(np.full(shape, z), rig, normalised=True)[:: cfg.stride]
            for z in (cfg.min_depth, rig.max_depth)]
    p, leaves = cfg.column_padding, math.prod(cfg.classes)
    ends = [(column.astype(np.float64) * (1 - 2 * p) + p) * leaves for column in ends]
    known = np.isfinite(ends[0]) & np.isfinite(ends[1])
    low = np.where(known, np.fmin(*ends), -np.inf)
    high = np.where(known, np.fmax(*ends), np.inf)
    widest = float(np.max(high[known] - low[known])) if known.any() else math.inf
    if widest < MIN_FEASIBLE_LEAVES:
        # span in leaves ~ k (1 / z - 1 / max_depth): the min_depth that gives MIN_FEASIBLE_LEAVES
        k = widest / (1 / cfg.min_depth - 1 / rig.max_depth)
        nearest = 1 / (MIN_FEASIBLE_LEAVES / k + 1 / rig.max_depth)
        raise ConfigError(f"[model] min_depth = {cfg.min_depth:g} m is too close to the rig's max_depth "
                          f"{rig.max_depth:g} m: the projector columns of depths between them span at most "
                          f"{widest:.2f} of the tree's {leaves} leaves, so no level has a class left to "
                          f"choose and nothing is learnt (loss 0); allowed: 0 (every class) or at most "
                          f"{nearest:.3g} m")
    return torch.from_numpy(np.stack([low, high], -1).astype(np.float32))


def build_model(cfg: Config, rig: Rig) -> GigaDepthNet:
    """The network for this config on this rig's camera (output rows = ceil(H / stride)), choosing
    among the classes the rig's depth range allows where [model] min_depth is set."""
    return GigaDepthNet(cfg.model, rows=output_rows(cfg.model, rig.camera.height),
                        feasible=feasible_positions(cfg.model, rig))
