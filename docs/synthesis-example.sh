#!/bin/sh
# Rebuilds docs/synthesis-example.png, the README's photograph beside its synthesis, with the
# researcher's walk: a photograph shipped in scikit-image, a k-means mask, fit, synth.
# Run from the repository root after `make demo` or `make setup`: sh docs/synthesis-example.sh
set -e
BIN=.venv/bin
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
$BIN/python -c "import skimage.data, skimage.io; skimage.io.imsave('$WORK/gravel.png', skimage.data.gravel())"
$BIN/btf-host mask "$WORK/gravel.png" --method kmeans --k 3 --out "$WORK/mask.png"
$BIN/btf-host fit "$WORK/gravel.png" --mask "$WORK/mask.png" --json > "$WORK/models.json"
$BIN/btf-host synth --model "$WORK/models.json" --mask "$WORK/mask.png" --out "$WORK/synth.png"
$BIN/btf-host compare "$WORK/gravel.png" "$WORK/synth.png" --mask "$WORK/mask.png"
$BIN/python - "$WORK" <<'EOF'
import sys

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import skimage.io

work = sys.argv[1]
crop = (slice(0, 320), slice(0, 320))  # the full 512x512 makes a megabyte of noise-like PNG
panels = [
    ("photograph (skimage.data.gravel)", skimage.io.imread(f"{work}/gravel.png")[crop], "gray"),
    ("k-means mask, 3 classes", skimage.io.imread(f"{work}/mask.png")[crop], "viridis"),
    ("synthesized: 3 Johnson models and their grain", skimage.io.imread(f"{work}/synth.png")[crop], "gray"),
]
figure, axes = plt.subplots(1, 3, figsize=(12, 4.3))
for ax, (title, image, cmap) in zip(axes, panels):
    ax.imshow(image, cmap=cmap, vmin=0, vmax=255 if cmap == "gray" else None, interpolation="nearest")
    ax.set_title(title, fontsize=11)
    ax.axis("off")
figure.tight_layout()
figure.savefig("docs/synthesis-example.png", dpi=100)
print("wrote docs/synthesis-example.png")
EOF
