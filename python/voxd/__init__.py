"""voxd: read VOD files (the voxd project's brick-octree voxel files) into numpy.

    import voxd
    v = voxd.read("scene.vod", level=0)
    v.data      # numpy array, shape (z, y, x)
    v.origin, v.spacing, v.channel, v.metadata

The file is validated completely first (every brick's hash, the CRC), as
`vox info` does; a damaged file raises voxd.VodError with the same message.
docs/python.md says more.
"""

from ._vod import Volume, VodError, read, read_bytes, sfhs, xx32

__all__ = ["Volume", "VodError", "read", "read_bytes", "sfhs", "xx32"]
__version__ = "0.1.0"
