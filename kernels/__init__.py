"""Warp device code of stepterrain (installed as ``stepterrain.kernels``): kernels, device functions, structs.

Only ``warp`` and the standard library are imported here; the Python API in ``stepterrain`` launches these.

Every module that does floating-point work compiles with ``fuse_fp=False``: no multiply-add is contracted into
an FMA, so the float32 arithmetic is plain IEEE on both backends and the CPU and CUDA give the same bits
wherever a kernel calls no transcendental function. With contraction on (Warp's default) NVRTC and the CPU's
LLVM fuse different operations: the cube-sphere heights of the two differed by up to 0.27 m and adaptive
meshes by a few triangles. The tests compare the two devices bit for bit where CUDA is present.

Loops over many elements (a thread's chunk, a row run, a sweep line) are ``while`` loops: on the CPU backend
Warp (1.19) compiles a ``for x in range(a, b)`` with runtime bounds to an iterator object that costs about 3 ns
an iteration (a 4.2 M-element copy: 10.9 ms with ``range``, 3.7 ms as a ``while`` loop); loops with a constant
bound (``range(4)``) are unrolled and stay ``for`` loops.

Hot loops index their 1-D arrays through :mod:`.memory` (``load(a, i)``, ``store(a, i, v)``): Warp's ``a[i]``
wraps negative indices, which costs the CPU code a test and an add per access (a 4.2 M-node count loop: 21-28 ms
with ``a[i]``, 7.7 ms with ``load``). Those arrays must be contiguous (``stepterrain._device.to_device`` makes
them so) and the indices in range; Warp's debug mode asserts it (``tests/test_memory.py``).
"""
