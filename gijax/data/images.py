"""Reading camera images from ordinary image files (PNG, JPEG, ...) for inference.

Dataset images go through :mod:`gijax.data.reader`; this is for the files a user points a
command at (``gijax predict --images``, ``gijax trt run``; their masks are read by
:func:`gijax.io.masks.read_mask`), with :func:`fit_images`, the one image-size policy of every
method (JAX model, ONNX file, classical baseline).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gijax.geometry.rig import Rig, scale_rig


def read_image(path: str | os.PathLike, grey: bool = False) -> np.ndarray:
    """An image as uint8: RGB (h, w, 3), or (h, w) with ``grey`` (masks).

    Grey images are repeated to three channels, an alpha channel is dropped and 16-bit images
    are scaled to 8 bits. FileNotFoundError / ValueError name the file.
    """
    import cv2

    from gijax.io.jpeg import check_jpeg_complete, is_jpeg
    from gijax.io.png import PNG_SIGNATURE, check_png_chunks

    path = str(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such image")
    data = Path(path).read_bytes()
    # A truncated PNG or JPEG decodes partly (the rest grey or black) with only a warning from
    # the codec on stderr: checked from the bytes first, so that it is refused instead.
    problem = (check_png_chunks(data) if data.startswith(PNG_SIGNATURE)
               else check_jpeg_complete(data) if is_jpeg(data) else None)
    if problem:
        raise ValueError(f"{path}: {problem}")
    img = cv2.imdecode(np.frombuffer(data, np.uint8),
                       cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    if grey:
        return img
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    elif img.shape[-1] == 4:
        img = img[..., :3]
    if img.dtype == np.uint16:
        img = (img / 257.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(img[..., ::-1])  # OpenCV reads BGR


def read_images(paths) -> np.ndarray:
    """One image per camera (``paths`` in camera order) stacked as uint8 (Ncam, h, w, 3); a
    ValueError names the first file whose size differs from the first one's."""
    images = [read_image(p) for p in paths]
    first = images[0].shape[:2]
    for path, im in zip(paths, images):
        if im.shape[:2] != first:
            raise ValueError(f"{path}: image is {_size_text(im.shape[:2])} but {paths[0]} is "
                             f"{_size_text(first)}; give every camera's image at one size")
    return np.stack(images)


def _size_text(hw) -> str:
    return f"{hw[0]} x {hw[1]}"


def fit_images(rig: Rig, images, masks=None, size: tuple[int, int] | None = None,
               log=None) -> tuple[Rig, np.ndarray, np.ndarray | None]:
    """The one image-size policy of every method: images of another size than the method works
    at are resized when their aspect ratio is the rig's, and refused otherwise.

    Args:
      rig: the rig at its calibrated image size (cameras of one size).
      images: (N, h, w, C) images, all of one size; ``masks`` (N, h, w) or None.
      size: (height, width) the method works at (the learned model: the rig's size times its
        ``image_scale``), or None to work at the images' own size (the classical baseline
        resamples every image to its matching view anyway, so only the lens is rescaled).
      log: called with a one-line note when anything is resized or rescaled.

    Returns the rig at the working size, and the images and masks at that size (float32 masks
    where resized). Raises ValueError naming the expected and found sizes when the aspect
    ratio differs (a crop or another camera, not a resize).
    """
    import cv2

    images = np.asarray(images)
    cam = rig.cameras[0]
    rig_hw = (cam.height, cam.width)
    found = tuple(int(x) for x in images.shape[1:3])
    wanted = found if size is None else tuple(int(x) for x in size)
    # Same aspect within the one pixel that rounding a scaled size can lose.
    if abs(found[0] - rig_hw[0] * found[1] / rig_hw[1]) > 1.0:
        need = "" if size is None else f"; the model works at {_size_text(wanted)}"
        raise ValueError(f"images must be {_size_text(rig_hw)} (the rig's size{need}) or "
                         f"another size of the same aspect ratio; found {_size_text(found)}")
    factor = wanted[1] / rig_hw[1]
    run_rig = rig if wanted == rig_hw else scale_rig(rig, factor)
    run_hw = (run_rig.cameras[0].height, run_rig.cameras[0].width)
    if run_hw != wanted:
        raise ValueError(f"the rig's {_size_text(rig_hw)} cameras scaled by {factor:g} are "
                         f"{_size_text(run_hw)}, not the {_size_text(wanted)} asked for")
    if found != run_hw:
        # Shrinking averages (INTER_AREA) so fine texture does not alias; enlarging
        # interpolates.
        inter = cv2.INTER_AREA if found[1] > run_hw[1] else cv2.INTER_LINEAR
        images = _resize(images, run_hw, inter)
        if masks is not None:
            masks = _resize(np.asarray(masks, np.float32), run_hw, inter)
        if log is not None:
            log(f"note: images {_size_text(found)} resized to {_size_text(run_hw)} (the rig's "
                f"{_size_text(rig_hw)} scaled by {factor:g}) for the model")
    elif run_rig is not rig and log is not None:
        log(f"note: images are {_size_text(found)}; the rig's {_size_text(rig_hw)} lenses are "
            f"rescaled by {factor:g} to match them")
    return run_rig, images, masks


def _resize(images: np.ndarray, hw: tuple[int, int], interpolation: int) -> np.ndarray:
    import cv2

    out = [cv2.resize(np.ascontiguousarray(im), (hw[1], hw[0]), interpolation=interpolation)
           for im in images]
    return np.stack([o.reshape(hw[0], hw[1], *im.shape[2:]) for o, im in zip(out, images)])
