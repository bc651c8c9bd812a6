"""`diffblur synth` on eight photographs (scikit-image's bundled ones, long side at most 640 px):
times the command and draws four of the pairs (docs/synth_pairs.png).

    PYTHONPATH=. python scripts/make_synth_pairs.py --workers 2 --out /tmp/synth_demo
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field", "immunohistochemistry", "retina", "colorwheel")
LONG_SIDE = 640


def write_photos(folder: Path) -> None:
    import skimage.data
    import skimage.transform
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    for name in PHOTOS:
        image = getattr(skimage.data, name)()[:, :, :3]
        scale = min(1.0, LONG_SIDE / max(image.shape[:2]))
        if scale < 1:
            image = skimage.transform.rescale(image, scale, channel_axis=2, anti_aliasing=True)
            image = np.round(255 * image).astype(np.uint8)
        Image.fromarray(image).save(folder / f"{name}.png")


def draw(out: Path, picture: Path, names: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    figure, axes = plt.subplots(2, len(names), figsize=(3.2 * len(names), 6.4))
    for column, name in enumerate(names):
        record = json.loads((out / f"{name}.json").read_text())
        motion = record["motion"]
        what = f"pan {np.hypot(*motion['velocity']) * 2:.0f} px" if motion["kind"] == "pan" else f"shake, path {np.hypot(*np.subtract(motion['offset_next'], motion['offset_prev'])):.0f} px"
        camera = record["camera"]
        noise = f"shot {camera['shot_noise']:.3f}, read {camera['read_noise']:.3f}"
        jpeg = "" if camera["jpeg_quality"] is None else f", JPEG {camera['jpeg_quality']}"
        for row, key in enumerate(("sharp", "blurred")):
            axes[row, column].imshow(Image.open(out / record["files"][key]))
            axes[row, column].set_xticks([])
            axes[row, column].set_yticks([])
        axes[0, column].set_title(f"{name}: sharp", fontsize=9)
        axes[1, column].set_title(f"{what}, {record['shutter']}\n{noise}{jpeg}", fontsize=8)
    figure.tight_layout()
    figure.savefig(picture, dpi=80)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="/tmp/synth_demo", help="working folder (photos/ and pairs/)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--picture", default="docs/synth_pairs.png")
    args = parser.parse_args()
    photos, pairs = Path(args.out) / "photos", Path(args.out) / "pairs"
    write_photos(photos)
    command = [sys.executable, "-m", "diffblur", "synth", str(photos), str(pairs), "--seed", str(args.seed), "--workers", str(args.workers), "--jpeg", "75", "95"]
    start = time.perf_counter()
    subprocess.run(command, check=True, env={**os.environ})
    seconds = time.perf_counter() - start
    sizes = [f"{name} {'x'.join(map(str, reversed(np.asarray(__import__('PIL.Image').Image.open(photos / f'{name}.png')).shape[:2])))}" for name in PHOTOS]
    print(f"{len(PHOTOS)} photographs ({', '.join(sizes)}): {seconds:.1f} s with --workers {args.workers}, process start and imports included")
    draw(pairs, Path(args.picture), list(PHOTOS[:4]))
    print(f"wrote {args.picture}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
