"""Figure of a distillation run: test MSE and SP (with its 95 % interval) per epoch."""

from __future__ import annotations

from pathlib import Path


def plot_history(history: list[dict], path: Path, title: str = "") -> Path:
    """Two panels over epochs: train/test MSE (log scale) and SP [%] with its bootstrap interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_mse, ax_sp) = plt.subplots(1, 2, figsize=(10, 3.8))
    epochs = [r["epoch"] for r in history]
    ax_mse.plot(epochs, [r["train_loss"] for r in history], "o-", label="train")
    ax_mse.plot(epochs, [r["test_mse"] for r in history], "s-", label="test (held out)")
    ax_mse.set_yscale("log")
    ax_mse.set_xlabel("epoch")
    ax_mse.set_ylabel("MSE (label space)")
    ax_mse.legend()
    with_sp = [r for r in history if r.get("sp")]
    if with_sp:
        e = [r["epoch"] for r in with_sp]
        sp = [100 * r["sp"]["sp"] for r in with_sp]
        lo = [100 * r["sp"]["ci95"][0] for r in with_sp]
        hi = [100 * r["sp"]["ci95"][1] for r in with_sp]
        ax_sp.plot(e, sp, "o-", color="C2", label=f"SP (n={with_sp[-1]['sp']['episodes']} episodes)")
        ax_sp.fill_between(e, lo, hi, color="C2", alpha=0.25, label="95 % CI")
        ax_sp.axhline(100, color="k", lw=0.8, ls="--")
        ax_sp.legend()
    ax_sp.set_xlabel("epoch")
    ax_sp.set_ylabel("SP [%] (0 untrained, 100 expert)")
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
