"""Draw the figures of docs/model.md from clisp's own definitions (no data files needed).

    python tools/docs_figures.py [--out docs/figures]

cfa.png     the LMS CFA's 4 x 4 tile over an 8 x 8 patch, the same CFA at phase (1, 2), and Bayer RGGB
            (from clisp.cfa: what the simulator mosaics and the pipeline demosaics)
spectrum.png  where each colour sits in the frequency plane of an LMS and a Bayer mosaic: the
            magnitude of each channel's carrier at the 16 (resp. 4) frequencies of the tile
noise.png   per-pixel raw SNR against the normalised signal at gains 1 to 64 (clisp.sim.noise's model)
"""
from __future__ import annotations

import argparse

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.cfa import CFA, bayer_cfa, lms_cfa
from clisp.sim.noise import NoiseModel

COLOURS = {"L": "#d62728", "M": "#2ca02c", "S": "#1f77b4", "R": "#d62728", "G": "#2ca02c", "B": "#1f77b4"}


def draw_cfa(ax, cfa: CFA, size: int, title: str) -> None:
    """``size`` x ``size`` pixels of ``cfa``, each cell coloured and lettered by its channel; the
    first period is outlined."""
    from matplotlib.patches import Rectangle
    for y in range(size):
        for x in range(size):
            name = cfa.channels[cfa.pattern[y % cfa.period, x % cfa.period]]
            ax.add_patch(Rectangle((x, y), 1, 1, facecolor=COLOURS[name], alpha=0.75, edgecolor="white"))
            ax.text(x + 0.5, y + 0.5, name, ha="center", va="center", color="white", fontsize=9, weight="bold")
    p = cfa.period
    ax.add_patch(Rectangle((0, 0), p, p, fill=False, edgecolor="black", linewidth=2))
    ax.set_xlim(0, size)
    ax.set_ylim(size, 0)
    ax.set_aspect("equal")
    ax.set_xticks(np.arange(size) + 0.5, [str(i) for i in range(size)], fontsize=7)
    ax.set_yticks(np.arange(size) + 0.5, [str(i) for i in range(size)], fontsize=7)
    ax.tick_params(length=0)
    ax.set_title(title, fontsize=9)


def carriers(cfa: CFA) -> np.ndarray:
    """|a_c(w)| for each channel c at each frequency w = 2 pi (ky, kx) / period of the tile:
    (n_channels, period, period), frequencies shifted so that (0, 0) is in the middle."""
    p = cfa.period
    out = np.empty((cfa.n_channels, p, p))
    for c in range(cfa.n_channels):
        mask = (cfa.pattern == c).astype(float)
        out[c] = np.abs(np.fft.fftshift(np.fft.fft2(mask))) / (p * p)
    return out


def draw_spectrum(fig, row: int, cfa: CFA, label: str) -> None:
    p = cfa.period
    names = {-1.0: "−π", -0.5: "−π/2", 0.0: "0", 0.5: "π/2"}
    ticks = [names[2 * k / p] for k in range(-(p // 2), p - p // 2)]
    magnitude = carriers(cfa)
    for c, name in enumerate(cfa.channels):
        ax = fig.add_subplot(2, 3, 3 * row + c + 1)
        ax.imshow(magnitude[c], cmap="Greys", vmin=0, vmax=0.5)
        for (ky, kx), v in np.ndenumerate(magnitude[c]):
            if v > 1e-9:
                ax.text(kx, ky, f"{v:.3g}", ha="center", va="center", fontsize=7,
                        color="white" if v > 0.25 else COLOURS[name])
        ax.set_xticks(range(p), ticks, fontsize=6)
        ax.set_yticks(range(p), ticks, fontsize=6)
        ax.set_title(f"{label}: {name}", fontsize=9, color=COLOURS[name])
        if c == 0:
            ax.set_ylabel("ω_y", fontsize=8)
        ax.set_xlabel("ω_x", fontsize=8)


def raw_snr_db(model: NoiseModel, gain: float, signal: np.ndarray) -> np.ndarray:
    """Per-pixel SNR of a raw value (black-subtracted, normalised; white = 1) at analog ``gain``:
    mean over the standard deviation of the model's shot, read and quantisation noise."""
    n = model.full_scale_electrons(gain)
    step = 1.0 / model.dn_per_electron(gain)                  # electrons per DN
    electrons = signal * n
    return 20 * np.log10(electrons / np.sqrt(electrons + model.read_noise_e ** 2 + step ** 2 / 12))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_out_option(parser, "docs/figures", "the figures")
    args = parser.parse_args(argv)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = args.out
    out.mkdir(parents=True, exist_ok=True)

    fig, axes = plt.subplots(1, 3, figsize=(9, 3.3))
    draw_cfa(axes[0], lms_cfa(), 8, "LMS, phase (0, 0)")
    draw_cfa(axes[1], lms_cfa((1, 2)), 8, "LMS, phase (1, 2)")
    draw_cfa(axes[2], bayer_cfa("RGGB"), 8, "Bayer RGGB")
    fig.tight_layout()
    fig.savefig(out / "cfa.png", dpi=80)
    plt.close(fig)

    fig = plt.figure(figsize=(9, 6))
    draw_spectrum(fig, 0, lms_cfa(), "LMS")
    draw_spectrum(fig, 1, bayer_cfa("RGGB"), "Bayer")
    fig.tight_layout()
    fig.savefig(out / "spectrum.png", dpi=80)
    plt.close(fig)

    model = NoiseModel()
    signal = np.logspace(-3, 0, 200)
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for gain in (1, 4, 8, 16, 32, 64):
        ax.semilogx(signal, raw_snr_db(model, gain, signal), label=f"gain {gain}")
    ax.set_xlabel("raw signal (black-subtracted, white = 1)")
    ax.set_ylabel("per-pixel SNR (dB)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "noise.png", dpi=80)
    plt.close(fig)
    for name in ("cfa.png", "spectrum.png", "noise.png"):
        print(f"{out / name}: {(out / name).stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
