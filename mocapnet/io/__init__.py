"""File formats: BVH (joint angles) and C3D (marker positions)."""

from mocapnet.io.atomic import MocapFileError, atomic_output
from mocapnet.io.bvh import read_bvh, write_bvh
from mocapnet.io.c3d import read_c3d, write_c3d

__all__ = ["MocapFileError", "atomic_output", "read_bvh", "write_bvh", "read_c3d", "write_c3d"]
