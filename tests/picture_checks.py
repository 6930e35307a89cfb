"""What a saved picture shows: how many of its pixels carry a given colour."""
import numpy as np
from PIL import Image

# matplotlib's tab palette, which the zone plots use.
TAB_RGB = {"blue": (31, 119, 180), "orange": (255, 127, 14), "green": (44, 160, 44), "red": (214, 39, 40)}


def pixels_of_colour(path, rgb, tolerance=40, columns=(0.0, 1.0)) -> int:
    """Pixels of the image at ``path`` within ``tolerance`` (Euclidean, 0-255 RGB) of ``rgb``, counted
    in the band of ``columns`` (fractions of the width: (0, 0.5) is the left panel of two)."""
    with Image.open(path) as image:
        pixels = np.asarray(image.convert("RGB"), dtype=np.float32)
    width = pixels.shape[1]
    pixels = pixels[:, int(columns[0] * width):int(columns[1] * width)]
    return int((np.linalg.norm(pixels - np.asarray(rgb, dtype=np.float32), axis=-1) <= tolerance).sum())
