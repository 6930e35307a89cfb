"""Import Open3D on machines without the system ``libusb-1.0``.

Open3D's wheels link ``libusb-1.0.so.0`` dynamically; minimal images lack it. The
``libusb-package`` wheel ships the library, so loading it globally before the import makes
``import open3d`` work without a system package.
"""
from __future__ import annotations

import ctypes


def _load_bundled_libusb() -> None:
    import libusb_package

    path = libusb_package.get_library_path()
    if path is None:
        raise ImportError("open3d needs libusb-1.0 and libusb-package ships none for this platform")
    ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


try:
    import open3d as o3d
except ImportError as first_error:
    if "libusb" not in str(first_error):
        raise
    _load_bundled_libusb()
    import open3d as o3d

__all__ = ["o3d"]
