"""The HeightNet v2 learning curve: held-out object-top error per class against images seen.

    python -m heightnet.contact_curve RUN_DIR[,RUN_DIR...] --out docs/heightnet_v2_curve.png

Reads each run's ``curve.csv`` (written by ``heightnet/contact_train.py`` every ``eval_every``
steps); one panel with the true camera, one with only the camera height (camera heads).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

Y_MAX_CM = 150.0   # values above are drawn at the top edge
CLASSES = (("person", "people"), ("cyclist", "cyclists"), ("car_van", "cars/vans"), ("truck_bus", "trucks/buses"))


def read_curve(path: Path) -> list[dict[str, float]]:
    with path.open(newline="") as f:
        # Columns added since a row was written (a grown network) are empty in it: NaN.
        return [{k: float(v) if v != "" else float("nan") for k, v in row.items()} for row in csv.DictReader(f)]


def plot_curves(runs: dict[str, list[dict[str, float]]], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    styles = ["-", "--", ":", "-."]
    for (name, rows), style in zip(runs.items(), styles):
        images = [r["images"] / 1000 for r in rows]
        for (key, label), colour in zip(CLASSES, ("tab:blue", "tab:green", "tab:orange", "tab:red")):
            for ax, prefix in zip(axes, ("top_", "top_heads_")):
                # A wild early camera-head guess can read kilometres: clip the drawing, not the data.
                ax.plot(images, [min(r[f"{prefix}{key}_cm"], Y_MAX_CM) for r in rows], style, color=colour,
                        marker=".", label=f"{label}" + (f" ({name})" if len(runs) > 1 else ""))
    axes[0].set_title("held-out object-top error, true camera")
    axes[1].set_title("same, camera height only (camera heads)")
    for ax in axes:
        ax.set_ylim(0, Y_MAX_CM)
        ax.set_xlabel("training images seen (thousands)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("median |error| (cm)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m heightnet.contact_curve", description=__doc__.split("\n")[0])
    parser.add_argument("runs", help="run folder(s) with curve.csv, comma-separated")
    parser.add_argument("--out", required=True, help="PNG to write")
    args = parser.parse_args(argv)
    runs = {}
    for folder in args.runs.split(","):
        path = Path(folder) / "curve.csv"
        if not path.is_file():
            print(f"error: {path} not found", file=sys.stderr)
            return 2
        runs[Path(folder).name] = read_curve(path)
    plot_curves(runs, Path(args.out))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
