"""mocapnet: clean motion-capture data — denoise and fill gaps in BVH and C3D recordings.

``import mocapnet`` is light (numpy/scipy only); the networks live in ``mocapnet.nn`` and import torch.
"""

from mocapnet.io import MocapFileError, read_bvh, read_c3d, write_bvh, write_c3d
from mocapnet.motion import Markers, Motion, Skeleton

__version__ = "0.1.0"

__all__ = ["Markers", "MocapFileError", "Motion", "Skeleton", "read_bvh", "read_c3d", "write_bvh", "write_c3d"]
