"""Procedural datasets: rendered samples written in the dataset format, resumable.

:func:`render_dataset` is what ``gijax render`` does (and what the experiments call for their
training, validation and test data): sample ``i`` is rendered from ``sample_seed(seed, i)``
(recorded in the CSV), the requested count goes into the manifest first (an interrupted dataset
reads as incomplete), writing is crash-safe and a second call resumes after the last complete
sample. The settings that determine the samples' content are recorded in the manifest, so a
call with other settings on the same folder is refused instead of mixing two datasets.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Optional

from gijax.data.writer import DatasetWriter, sample_seed
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig, scale_rig

RENDERER = "gijax.render.render_sample"


def render_dataset(rig: Rig, out: str | os.PathLike, samples: int, *, seed: int = 0,
                   image_scale: float = 1.0, pano: Panorama = Panorama.hemisphere(160, 640),
                   style: str = "mixed", trajectory_size: int = 1000, durable: bool = False,
                   progress: bool = True, log: Optional[Callable[[str], None]] = None) -> Rig:
    """Render ``samples`` samples of ``rig`` (its images scaled by ``image_scale``) into the
    dataset folder ``out``, or resume it; returns the rig the samples were rendered with.

    ``pano`` is the ground-truth panorama, ``style`` 'mixed', 'indoor' or 'outdoor'. ``log``
    receives one line when the folder already holds samples.
    """
    from tqdm import tqdm

    from gijax.io.paths import check_output_dir
    from gijax.render import SCENE_VERSION, render_sample

    if samples < 1:
        raise ValueError(f"a dataset needs at least 1 sample; found {samples}")
    check_output_dir(out)
    say = log or (lambda _line: None)
    scaled = rig if image_scale == 1.0 else scale_rig(rig, image_scale)
    # The settings that determine every sample's content; the target count is not one of them,
    # so a later call may extend the dataset.
    generator = {"renderer": RENDERER, "scene_version": SCENE_VERSION, "seed": int(seed),
                 "style": style, "image_scale": image_scale}
    with DatasetWriter(Path(out), scaled, pano, trajectory_size=trajectory_size,
                       generator=generator, durable=durable) as writer:
        done = writer.num_committed
        writer.request(samples)
        if done >= samples:
            say(f"{out}: already holds {done} samples (asked for {samples}); nothing to do")
            return scaled
        if done:
            say(f"{out}: resuming after {done} complete samples")
        with tqdm(total=samples, initial=done, unit="sample", desc="render",
                  disable=not progress) as bar:
            for i in range(done, samples):
                seed_i = sample_seed(seed, i)
                writer.write(render_sample(scaled, seed_i, pano=pano, style=style), seed=seed_i)
                bar.update(1)
    return scaled
