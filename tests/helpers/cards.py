"""A grey card pasted into a copy of a photo-like target (optimize/card_region.py): what a shoot with one gives.

The shipped photo-like targets (benchmarks/make_photo_targets.py) are Cycles renders as a camera saved them, with
the gains and white balance in camera_truth.json. A card of reflectance ρ facing `normal` in a view's light has
radiance L (warp_hair.grey_card), so the camera records G_kc · L_c there: that value, sRGB-encoded to the file's
8-bit codes, is pasted over a square of the view (the hair fills the frame: the card hides what is behind it),
with its mask beside it and target.toml told of both.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
from PIL import Image

from warp_hair.grey_card import card_normal, card_radiance
from warp_hair.io import srgb_encode
from warp_hair.scene import load_scene


def with_card(source, directory, views=("front",), box=(0, 8, 0, 8), reflectance=0.18, normal="camera", exif=False):
    """Copy the PNG photo target `source` to `directory` with a card pasted into `views` over the rows and
    columns box = (y0, y1, x0, x1); returns {view: the card's linear value in the file (3,)}. exif: also give
    every view the EXIF exposure a manual shoot records (its true gain as the exposure time, f/4, ISO 100) and
    fit the gains as EXIF ties them (gains = "exif")."""
    shutil.copytree(source, directory)
    truth = json.loads((directory / "camera_truth.json").read_text())
    spec = (directory / "target.toml").read_text()
    if exif:
        for view, gain in truth["gains"].items():
            record = Image.Exif()
            sub = record.get_ifd(0x8769)
            sub[0x829A], sub[0x829D], sub[0x8827] = float(gain), 4.0, 100  # ExposureTime, FNumber, ISO
            record[0x010F] = "synthetic"  # Make: Pillow writes no PNG eXIf chunk whose main IFD is empty
            path = directory / f"{view}.png"
            Image.open(path).convert("RGB").save(path, exif=record)
        spec = 'gains = "exif"\n' + spec
    pasted = {}
    y0, y1, x0, x1 = box
    for view in views:
        scene = load_scene(directory / f"scene_{view}.toml")
        radiance = card_radiance(scene, reflectance, card_normal(scene, normal))
        value = truth["gains"][view] * np.asarray(truth["white_balance"]) * radiance
        path = directory / f"{view}.png"
        with Image.open(path) as opened:
            codes, record = np.asarray(opened.convert("RGB")).copy(), opened.getexif()
        codes[y0:y1, x0:x1] = np.round(srgb_encode(value) * 255.0).astype(np.uint8)
        Image.fromarray(codes, "RGB").save(path, exif=record)
        mask = np.zeros(codes.shape[:2], np.uint8)
        mask[y0:y1, x0:x1] = 255
        Image.fromarray(mask, "L").save(directory / f"{view}_card.png")
        spec = spec.replace(f'image = "{view}.png"', f'image = "{view}.png"\ncard_mask = "{view}_card.png"')
        pasted[view] = value
    if not views:
        (directory / "target.toml").write_text(spec)
        return pasted
    normal_text = '"camera"' if isinstance(normal, str) else json.dumps(list(normal))
    head, images = spec.split("[[images]]", 1)
    card = f"[card]\nreflectance = {json.dumps(reflectance)}\nnormal = {normal_text}\n\n"
    (directory / "target.toml").write_text(head + card + "[[images]]" + images)
    return pasted
