"""Train a StreetGAN generator (Hartmann thesis ch. 4.2.4) and export it to ONNX.

Training only: needs PyTorch (``requirements-train.txt``, venv ``build/train-venv``); the
plugin runs the exported generator with onnxruntime and never imports torch.

    build/train-venv/bin/python tools/streetgan/train.py build/streetgan/helsinki.npz \
        resources/models/streetgan_helsinki --epochs 12

Model: the spatial GAN (SGAN) of Jetchev et al. 2016 that the thesis adapted to one
channel. Fully convolutional: z in R^(100 x m x m), uniform in [-1, 1]; five stride-2
5 x 5 transposed convolutions give 32 (m - 1) + 1 pixels (m = 11 -> 321, m = 25 -> 769);
the discriminator mirrors it with five stride-2 convolutions and answers one logit per
spatial position. Losses (thesis eq. 4.2.3): J(D) = -1/2 E log D(x) - 1/2 E log(1 - D(G(z))),
non-saturating J(G) = -1/2 E log D(G(z)); Adam (lr 5e-4, beta1 0.5, L2 1e-5: the SGAN
reference code); an epoch is 100 iterations (thesis). Patches of 321 x 321 px are cut at
random places of the training image and turned by one of the 8 rotations / reflections.

CPU budget: the filter counts are a quarter of SGAN's (16 .. 128 instead of 64 .. 512), the
batch is small and the shipped models were trained on 161 x 161 px patches (m = 6, a
quarter of the thesis's pixels per patch) on one niced thread of a shared 2-core CPU, see
their cards; on a GPU use the thesis's ``--patch 321 --batch 64 --filters 32 --epochs 100``.
The model is exported after every epoch, so a run can be stopped when time is up (the
thesis chose its epoch by eye). Deterministic for a given ``--seed`` (one thread,
deterministic algorithms): ``--epochs N`` reproduces epoch N of a longer run.

``--device cuda`` (default ``auto``: a GPU when torch sees one) trains there; patches and
noise are still drawn on the CPU from the same generators, so a run is reproducible on the
same GPU and software (cuDNN's deterministic kernels), not bit for bit against the CPU.
``--minutes M`` stops after the first epoch that ends past M minutes (a GPU lease).

Writes ``<out>.onnx`` (the generator, eval mode, dynamic spatial size), ``<out>.json`` (the
model card: data, architecture, epochs, losses, timing, sha256 of the ONNX file) and
``<out>_untrained.onnx`` next to the output unless ``--no-untrained`` (the raw generator, a
baseline for the evaluation).
"""
from __future__ import annotations

import argparse
import copy
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

NZ = 100
LAYERS = 5


def generator(filters: int) -> nn.Sequential:
    ch = [NZ] + [filters * 2 ** (LAYERS - 2 - i) for i in range(LAYERS - 1)] + [1]
    mods = []
    for i in range(LAYERS):
        # kernel 5, stride 2, padding 2: n -> 2 (n - 1) + 1
        mods.append(nn.ConvTranspose2d(ch[i], ch[i + 1], 5, stride=2, padding=2, bias=i == LAYERS - 1))
        mods += [nn.BatchNorm2d(ch[i + 1]), nn.ReLU(True)] if i < LAYERS - 1 else [nn.Tanh()]
    return nn.Sequential(*mods)


def discriminator(filters: int) -> nn.Sequential:
    ch = [1] + [filters * 2 ** i for i in range(LAYERS - 1)] + [1]
    mods = []
    for i in range(LAYERS):
        mods.append(nn.Conv2d(ch[i], ch[i + 1], 5, stride=2, padding=2, bias=i in (0, LAYERS - 1)))
        if i < LAYERS - 1:
            if i > 0:
                mods.append(nn.BatchNorm2d(ch[i + 1]))
            mods.append(nn.LeakyReLU(0.2, True))
    return nn.Sequential(*mods)  # logits, one per spatial position


def init_weights(m):
    if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
        nn.init.normal_(m.weight, 0.0, 0.02)
        if m.bias is not None:
            nn.init.zeros_(m.bias)
    elif isinstance(m, nn.BatchNorm2d):
        nn.init.normal_(m.weight, 1.0, 0.02)
        nn.init.zeros_(m.bias)


def patch_corners(inside: np.ndarray, size: int, min_inside: float = 0.5) -> np.ndarray:
    """Top-left corners (row, col) of the size x size windows of an image with at least
    ``min_inside`` of their pixels inside the mapped area (an integral image)."""
    s = np.pad(np.cumsum(np.cumsum(inside.astype(np.int64), 0), 1), ((1, 0), (1, 0)))
    rows, cols = inside.shape
    if rows < size or cols < size:
        return np.zeros((0, 2), np.int64)
    tot = s[size:, size:] - s[:-size, size:] - s[size:, :-size] + s[:-size, :-size]
    return np.argwhere(tot >= min_inside * size * size)


def patches(images, corners, n: int, size: int, rng: np.random.Generator) -> torch.Tensor:
    """n random size x size patches in [-1, 1], each turned by one of the 8 symmetries;
    an image is drawn with probability proportional to its number of usable windows."""
    counts = np.array([len(c) for c in corners], dtype=float)
    out = np.empty((n, 1, size, size), np.float32)
    for k in range(n):
        i = int(rng.choice(len(images), p=counts / counts.sum()))
        r, c = corners[i][rng.integers(0, len(corners[i]))]
        p = images[i][r:r + size, c:c + size]
        t = rng.integers(0, 8)
        p = np.rot90(p, t % 4)
        out[k, 0] = p.T if t >= 4 else p
    return torch.from_numpy(out / 127.5 - 1.0)


def noise(n: int, m: int, gen: torch.Generator) -> torch.Tensor:
    return torch.rand(n, NZ, m, m, generator=gen) * 2.0 - 1.0


def export(g: nn.Module, path: Path) -> str:
    g.eval()
    torch.onnx.export(g, noise(1, 11, torch.Generator().manual_seed(0)), str(path),
                      input_names=["z"], output_names=["image"], opset_version=17,
                      dynamic_axes={"z": {0: "batch", 2: "m_rows", 3: "m_cols"},
                                    "image": {0: "batch", 2: "rows", 3: "cols"}},
                      dynamo=False)
    return hashlib.sha256(path.read_bytes()).hexdigest()


def recalibrate_bn(g: nn.Module, m: int, gen: torch.Generator, batches: int = 6, n: int = 4):
    """Exact population statistics for BatchNorm: the exported generator runs in eval mode,
    and running averages of a short training lag behind the final weights."""
    for mod in g.modules():
        if isinstance(mod, nn.BatchNorm2d):
            mod.reset_running_stats()
            mod.momentum = None  # cumulative average
    g.train()
    device = next(g.parameters()).device
    with torch.no_grad():
        for _ in range(batches):
            g(noise(n, m, gen).to(device))


def save(g, args, meta, m, history, t0) -> Path:
    """Export the generator as it is now (after each epoch: a run can be stopped at any time
    and the last completed epoch is the model; the thesis picked its epoch by eye)."""
    g = copy.deepcopy(g)
    recalibrate_bn(g, m, torch.Generator().manual_seed(args.seed + 1))
    g = g.cpu()
    onnx_path = args.out.with_suffix(".onnx")
    sha = export(g, onnx_path)
    card = {
        "name": args.name or args.out.name,
        "title": args.title or args.out.name,
        "method": "StreetGAN (Hartmann thesis ch. 4.2): spatial GAN of Jetchev et al. 2016, "
                  "non-saturating loss, Adam",
        "training_data": meta,
        "cell_size_m": meta["cell_size_m"],
        "line_width_px": meta["line_width_px"],
        "input": {"name": "z", "channels": NZ, "distribution": "uniform[-1, 1]",
                  "layout": "N x 100 x m_rows x m_cols"},
        "output": {"name": "image", "channels": 1, "range": "tanh [-1, 1], road > 0",
                   "size": "32 (m - 1) + 1 per axis"},
        "upsampling_layers": LAYERS, "scale": 2 ** LAYERS,
        "generator_filters": [args.filters * 2 ** (LAYERS - 2 - i) for i in range(LAYERS - 1)],
        "generator_parameters": int(sum(p.numel() for p in g.parameters())),
        "training": {"initialised_from": args.init_onnx.name if args.init_onnx else None,
                     "patch_px": args.patch, "min_inside": args.min_inside, "noise_m": m,
                     "batch": args.batch,
                     "epochs": len(history), "iterations_per_epoch": args.iterations,
                     "iterations": len(history) * args.iterations, "lr": args.lr,
                     "betas": [0.5, 0.999], "weight_decay": 1e-5, "seed": args.seed,
                     "augmentation": "8 rotations/reflections", "threads": args.threads,
                     "device": args.device_name, "seconds": round(time.time() - t0, 1),
                     "torch": torch.__version__, "losses": history},
        "onnx_sha256": sha,
        # the plugin's default dead-end pruning for this model (streetgan.synthesize)
        "postprocess": {"min_dead_end_m": args.min_dead_end, "erosions": args.erosions,
                        "dilations": args.dilations},
    }
    onnx_path.with_suffix(".json").write_text(json.dumps(card, indent=1))
    return onnx_path


def main() -> None:
    ap = argparse.ArgumentParser(description="Train a StreetGAN generator (thesis ch. 4.2)")
    ap.add_argument("data", type=Path, nargs="+",
                    help="npz files from tools/streetgan/prepare.py (patches from all)")
    ap.add_argument("--held-out", default="",
                    help="comma-separated names of networks kept out of training (card)")
    ap.add_argument("out", type=Path, help="output path without suffix")
    ap.add_argument("--epochs", type=int, default=12)
    ap.add_argument("--iterations", type=int, default=100, help="iterations per epoch (thesis 100)")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--patch", type=int, default=321)
    ap.add_argument("--filters", type=int, default=16)
    ap.add_argument("--lr", type=float, default=5e-4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--name", default=None)
    ap.add_argument("--title", default="")
    ap.add_argument("--no-untrained", action="store_true")
    ap.add_argument("--init-onnx", type=Path, default=None,
                    help="start the generator from this exported model (a fine-tune)")
    ap.add_argument("--snapshots", type=Path, default=None,
                    help="also keep every epoch's generator as <dir>/epoch_<n>.onnx (+ card)")
    ap.add_argument("--min-dead-end", type=float, default=25.0,
                    help="dead ends this short (m) are pruned by default for this model "
                         "(thesis 25; choose on validation seeds)")
    ap.add_argument("--erosions", type=int, default=1,
                    help="erosions of the road mask before thinning for this model (thesis 1)")
    ap.add_argument("--dilations", type=int, default=5,
                    help="dilations of the road mask before thinning for this model (thesis "
                         "5, for 15 px lines; 1 for 5 px lines)")
    ap.add_argument("--device", default="auto",
                    help="cpu, cuda or auto (cuda when torch sees a GPU)")
    ap.add_argument("--min-inside", type=float, default=0.5,
                    help="share of a patch that must lie inside the mapped area (outside is "
                         "drawn empty: a patch mostly outside a town teaches empty land)")
    ap.add_argument("--minutes", type=float, default=None,
                    help="stop after the first epoch that ends past this many minutes")
    args = ap.parse_args()
    if (args.patch - 1) % 32:
        ap.error("--patch must be 32 (m - 1) + 1, e.g. 161, 321")
    if args.device == "auto":
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(args.device)
    if device.type == "cuda":
        # cuBLAS needs a fixed workspace for deterministic results
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.backends.cudnn.benchmark = False
        args.device_name = torch.cuda.get_device_name(device)
    else:
        args.device_name = "cpu"

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    # on a GPU an op without a deterministic kernel warns instead of stopping the run
    torch.use_deterministic_algorithms(True, warn_only=device.type == "cuda")
    rng = np.random.default_rng(args.seed)
    zgen = torch.Generator().manual_seed(args.seed)
    images, corners, metas = [], [], []
    for path in args.data:
        data = np.load(path, allow_pickle=True)
        inside = data["inside"] if "inside" in data else np.ones_like(data["image"])
        c = patch_corners(inside, args.patch, args.min_inside)
        if not len(c):
            ap.error(f"{path}: no {args.patch} px window lies {args.min_inside:.0%} inside its "
                     "mapped area")
        images.append(data["image"])
        corners.append(c)
        meta = json.loads(path.with_suffix(".json").read_text())
        meta["patch_windows"] = int(len(c))
        metas.append(meta)
    meta = metas[0] if len(metas) == 1 else {
        "name": "+".join(m_["name"] for m_ in metas), "networks": metas,
        "source": " | ".join(m_["source"] for m_ in metas),
        "cell_size_m": metas[0]["cell_size_m"], "line_width_px": metas[0]["line_width_px"],
        "length_km": round(sum(m_["length_km"] for m_ in metas), 2),
        "sampling": "image drawn with probability proportional to its windows of the patch "
                    f"size that lie at least {args.min_inside:.0%} inside the mapped area",
        "held_out": [t for t in args.held_out.split(",") if t]}
    m = (args.patch - 1) // 32 + 1

    g, d = generator(args.filters), discriminator(args.filters)
    g.apply(init_weights)
    d.apply(init_weights)
    if args.init_onnx:
        # fine-tune: the generator's weights from an exported model of the same shape (its
        # ONNX initialisers carry the state-dict names); the discriminator starts afresh
        import onnx
        from onnx import numpy_helper

        init = {i.name: torch.from_numpy(numpy_helper.to_array(i).copy())
                for i in onnx.load(str(args.init_onnx)).graph.initializer}
        missing = [k for k in g.state_dict() if k not in init and "num_batches" not in k]
        if missing:
            ap.error(f"{args.init_onnx} is not a generator with {args.filters} base filters "
                     f"(missing {', '.join(missing[:3])})")
        g.load_state_dict(init, strict=False)
    g.to(device)
    d.to(device)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not args.no_untrained:
        raw = args.out.with_name(args.out.name + "_untrained.onnx")
        export(g, raw)
        g.train()
    opt_g = torch.optim.Adam(g.parameters(), lr=args.lr, betas=(0.5, 0.999), weight_decay=1e-5)
    opt_d = torch.optim.Adam(d.parameters(), lr=args.lr, betas=(0.5, 0.999), weight_decay=1e-5)
    bce = nn.BCEWithLogitsLoss()
    history, t0 = [], time.time()
    for epoch in range(args.epochs):
        ld_sum = lg_sum = 0.0
        for it in range(args.iterations):
            real = patches(images, corners, args.batch, args.patch, rng).to(device)
            fake = g(noise(args.batch, m, zgen).to(device))
            # discriminator: -1/2 E log D(x) - 1/2 E log(1 - D(G(z)))
            out_r, out_f = d(real), d(fake.detach())
            loss_d = 0.5 * (bce(out_r, torch.ones_like(out_r)) + bce(out_f, torch.zeros_like(out_f)))
            opt_d.zero_grad(set_to_none=True)
            loss_d.backward()
            opt_d.step()
            # generator, non-saturating: -1/2 E log D(G(z))
            out_g = d(fake)
            loss_g = 0.5 * bce(out_g, torch.ones_like(out_g))
            opt_g.zero_grad(set_to_none=True)
            loss_g.backward()
            opt_g.step()
            ld_sum += loss_d.detach()  # summed on the device: no wait for it each step
            lg_sum += loss_g.detach()
        history.append({"epoch": epoch + 1, "loss_d": round(float(ld_sum) / args.iterations, 4),
                        "loss_g": round(float(lg_sum) / args.iterations, 4),
                        "seconds": round(time.time() - t0, 1)})
        print(json.dumps(history[-1]), flush=True)
        onnx_path = save(g, args, meta, m, history, t0)
        if args.snapshots:
            args.snapshots.mkdir(parents=True, exist_ok=True)
            for suffix in (".onnx", ".json"):
                dest = args.snapshots / f"epoch_{epoch + 1}{suffix}"
                dest.write_bytes(onnx_path.with_suffix(suffix).read_bytes())
        if args.minutes is not None and time.time() - t0 > 60 * args.minutes:
            break
    print(f"wrote {onnx_path} ({onnx_path.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
