"""Two screenshots side by side, each scaled to one width and labelled in its top-left corner
(white on black), with a white gap between: README's before/after pictures (docs/city.png).

    python tools/side_by_side.py LEFT.png RIGHT.png --labels "offline: 14.4 m median" \
        "registered: 0.56 m median" --out docs/city.png [--width 720] [--gap 8]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont


def labelled(path: Path, label: str, width: int) -> Image.Image:
    """The image at `path` scaled to `width` pixels wide (aspect kept), `label` in a black box
    at its top-left corner."""
    image = Image.open(path).convert("RGB")
    image = image.resize((width, round(image.height * width / image.width)), Image.LANCZOS)
    draw = ImageDraw.Draw(image)
    try:
        font = ImageFont.truetype("DejaVuSans.ttf", 11)
    except OSError:
        font = ImageFont.load_default(size=11)
    draw.rectangle([4, 6, 12 + draw.textlength(label, font=font), 24], fill=(0, 0, 0))
    draw.text((8, 8), label, fill=(255, 255, 255), font=font)
    return image


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("left", type=Path)
    parser.add_argument("right", type=Path)
    parser.add_argument("--labels", nargs=2, required=True, metavar=("LEFT", "RIGHT"))
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--width", type=int, default=720, help="pixels, each half")
    parser.add_argument("--gap", type=int, default=8, help="white pixels between the halves")
    args = parser.parse_args(argv)
    halves = [
        labelled(p, t, args.width)
        for p, t in zip((args.left, args.right), args.labels, strict=True)
    ]
    height = max(h.height for h in halves)
    out = Image.new("RGB", (2 * args.width + args.gap, height), (255, 255, 255))
    out.paste(halves[0], (0, 0))
    out.paste(halves[1], (args.width + args.gap, 0))
    out.save(args.out, optimize=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
