"""Warp device code of stepterrain (installed as ``stepterrain.kernels``): kernels, device functions, structs.

Only ``warp`` and the standard library are imported here; the Python API in ``stepterrain`` launches these.
"""
