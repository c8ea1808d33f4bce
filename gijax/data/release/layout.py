"""The folder layout of the paper's released training code: file names, keys and frames.

The release's dataset class (``MultiViewCameraModelDataset``) and its manifest parser open a
folder holding::

    ROOT/
      manifest.json          "camera_models": {key: {"type": ..., model parameters}},
                             "samplers": [{"mvs_main_cam_model_for_cam": bool,
                                           "mvs_cam_key": "cam0" | ... | "rig",
                                           "sampler": {"cam_model_key": key, ...}}, ...]
      metadata.json          "cams": [{"image_frame": "cif0", ...}, ...]  (camera k = "cam<k>")
      frame_graph.json       "frames", "typical_poses", "transforms" (poses T_f0_f1)
      masks.json             "masks": [{"raw_camera": "cam0", "mask": "valid_mask_0.png"}, ...],
                             optional "masks_augmented" (same shape)
      data_partitions.json   {split: {environment: [trajectory folder | CSV path, ...]}}
      ENV/TRAJ/meta.json     {"selected_file_list": "<name>.csv"}
      ENV/TRAJ/<name>.csv    columns cam<k>_rgb_fisheye, rig_dist_fisheye (paths relative to
                             ENV/TRAJ; a CSV named directly in data_partitions.json holds paths
                             relative to ROOT)

Encodings (the release's ``mvs_utils.image_io``): colour images are read with OpenCV unchanged,
so their channels are BGR; distances are float32 metres whose four little-endian bytes are the
four channels of an 8-bit PNG (as OpenCV orders them); a mask pixel is valid where its
greyscale value is exactly 255.
"""

from __future__ import annotations

import numpy as np

from gijax.geometry.panorama import Panorama

MANIFEST = "manifest.json"
METADATA = "metadata.json"
FRAME_GRAPH = "frame_graph.json"
PARTITIONS = "data_partitions.json"
MASKS = "masks.json"
TRAJ_META = "meta.json"
# The release's defaults (MultiViewCameraModelDataset and its data module).
RGB_SUFFIX = "_rgb_fisheye"
DIST_SUFFIX = "_dist_fisheye"
RIG_KEY = "rig"
RIG_RAW_FRAME = "rif"       # hard-coded in the release (find_rig_raw_frame)
RIG_LABEL_FRAME = "rifs"    # map_camera_frame["rig"] of the release's configurations
LABEL_PANO = Panorama.hemisphere(160, 640)
# Rotation taking release-panorama (rifs) coordinates to gijax panorama coordinates.
R_G_FROM_E = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
