"""Unchecked element access for the hot loops: ``load(a, i)`` and ``store(a, i, v)`` on 1-D contiguous arrays.

Warp (1.19) indexes ``a[i]`` Python-style: a negative ``i`` wraps to ``i + len(a)``. On the CPU that costs a
sign test and a conditional add at every access, and it keeps the compiler from scheduling a loop's loads and
stores together. A loop that reads four neighbours' levels and writes four counts per node ran 21-28 ms over
4.2 M nodes with ``a[i]`` and 7.7 ms with these (one core of this machine's AMD EPYC, Warp 1.19; the same
output).

Contract: every array passed here is 1-D and contiguous (the kernels' own buffers and structs, all made by
``stepterrain._device`` or, for the globe's node arrays, ``stepterrain.globe``), and every index is in
``[0, len(a))``. In Warp's debug mode (``wp.config.mode = "debug"``, compiled without ``NDEBUG``) the assertion
below checks that; in release mode nothing does, which is the point. CUDA compiles the same pointer arithmetic.

Users: ``kernels/stepped.py``; the refinement and mesh output of ``kernels/cubesphere.py`` and the plane loops
of ``kernels/bounds.py`` (the globe's far view: kernels 31 -> 27 ms, see cubesphere's module docstring); the
hillshade and contour rows of ``kernels/texture.py`` (2-D, below).

Overloads: one per element type these kernels use (Warp resolves ``load``/``store`` by argument types).

``stream(a, i, v)`` (vec3d, vec3l, int32) is a streaming store for a big output written in one sweep, on the CPU;
``stream_large(a, i, v)`` (vec3d; vec3l and int32 for tests only) streams only into a destination of at least
STREAM_MIN_BYTES and stores plainly into a smaller one; see the comments above their definitions for when they pay
and what their launches must do.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3l = wp.types.vector(length=3, dtype=wp.int64)

_LOAD = "assert(i >= 0 && i < a.shape[0]);\nreturn a.data[i];"
_STORE = "assert(i >= 0 && i < a.shape[0]);\na.data[i] = v;"


# fmt: off
@wp.func_native(_LOAD)
def load(a: wp.array[wp.int32], i: wp.int32) -> wp.int32: ...  # pragma: no cover - native code
@wp.func_native(_LOAD)
def load(a: wp.array[wp.float32], i: wp.int32) -> wp.float32: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.float64], i: wp.int32) -> wp.float64: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec3], i: wp.int32) -> wp.vec3: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec2], i: wp.int32) -> wp.vec2: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec2i], i: wp.int32) -> wp.vec2i: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec3i], i: wp.int32) -> wp.vec3i: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec4], i: wp.int32) -> wp.vec4: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec4i], i: wp.int32) -> wp.vec4i: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec3d], i: wp.int32) -> wp.vec3d: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD)
def load(a: wp.array[wp.vec4d], i: wp.int32) -> wp.vec4d: ...  # pragma: no cover  # noqa: F811


@wp.func_native(_STORE)
def store(a: wp.array[wp.int32], i: wp.int32, v: wp.int32): ...  # pragma: no cover - native code
@wp.func_native(_STORE)
def store(a: wp.array[wp.float32], i: wp.int32, v: wp.float32): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.uint8], i: wp.int32, v: wp.uint8): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.vec3], i: wp.int32, v: wp.vec3): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.vec2], i: wp.int32, v: wp.vec2): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.vec2i], i: wp.int32, v: wp.vec2i): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.vec3i], i: wp.int32, v: wp.vec3i): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.vec4i], i: wp.int32, v: wp.vec4i): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[vec3l], i: wp.int32, v: vec3l): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE)
def store(a: wp.array[wp.vec3d], i: wp.int32, v: wp.vec3d): ...  # pragma: no cover  # noqa: F811

# 2-D: (i, j) through the array's byte strides, so views work too; 64-bit offsets (a 16384² float32 grid is 1 GiB)
_LOAD2 = (
    "assert(i >= 0 && i < a.shape[0] && j >= 0 && j < a.shape[1]);\n"
    "return *reinterpret_cast<decltype(a.data)>(reinterpret_cast<char*>(a.data) + (long long)i * a.strides[0]"
    " + (long long)j * a.strides[1]);"
)
_STORE2 = (
    "assert(i >= 0 && i < a.shape[0] && j >= 0 && j < a.shape[1]);\n"
    "*reinterpret_cast<decltype(a.data)>(reinterpret_cast<char*>(a.data) + (long long)i * a.strides[0]"
    " + (long long)j * a.strides[1]) = v;"
)


@wp.func_native(_LOAD2)
def load(a: wp.array2d[wp.float32], i: wp.int32, j: wp.int32) -> wp.float32: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_LOAD2)
def load(a: wp.array2d[wp.uint8], i: wp.int32, j: wp.int32) -> wp.uint8: ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE2)
def store(a: wp.array2d[wp.float32], i: wp.int32, j: wp.int32, v: wp.float32): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE2)
def store(a: wp.array2d[wp.uint8], i: wp.int32, j: wp.int32, v: wp.uint8): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_STORE2)
def store(a: wp.array2d[wp.vec4], i: wp.int32, j: wp.int32, v: wp.vec4): ...  # pragma: no cover  # noqa: F811
# fmt: on


# Streaming (non-temporal) stores, for a big output written in one sweep: a plain store first reads the cache
# line it writes (to own it), so writing 300 MB moves 600; a streaming store writes past the caches, whole lines
# at once. 13 M vec3l (312 MB) took 27 ms with store, 17 ms with stream, on one core of session 19's AMD EPYC; the
# stepped γ blend (6.5 M vec3d) 15.5-18 -> 10-11 ms there. The stepped emit kernels gained nothing there; on
# session 23's Intel Xeon streaming their faces, face levels, blended vertices and count_grid's prefixes did
# (the face pass 68 -> 42 ms at 2048²). Streaming into pages not yet mapped is slow on these VMs, so streamed
# outputs are touched first where they are new (stepterrain._device.touch_pages). Streaming stores are weakly
# ordered: a kernel that streams is launched with fence=True (stepterrain._device.launch), which runs
# drain_streams on the same thread after it, before any other thread may read the output. CUDA stores plainly.
#
# The three components go out as movnti of their bits. LLVM has no scalar-double non-temporal store on x86
# (only AMD's SSE4a movntsd): a double it cannot fold into a vector it stores plainly (vmovsd), and it folds a
# stored bit cast back into that double. Streaming the doubles directly kept the z of every vertex a plain
# store, so each line was written by both kinds and bounced between the cache and memory: on the Intel Xeon
# VM of session 23 the 2048² blend took 2.8-3.1 s instead of 17 ms (RESULTS "Session 23"). Adding
# ``a.ndim - 1`` (0: the arrays here are 1-D) to the bits makes them integers the optimizer cannot turn back.
_NT3 = """
#if defined(__CUDA_ARCH__)
a.data[i] = v;
#else
long long bits[3];
const double parts[3] = {v[0], v[1], v[2]};
__builtin_memcpy(bits, parts, sizeof(bits));
const long long zero = (long long)(a.ndim - 1);
long long* dst = reinterpret_cast<long long*>(&a.data[i][0]);
__builtin_nontemporal_store(bits[0] + zero, dst);
__builtin_nontemporal_store(bits[1] + zero, dst + 1);
__builtin_nontemporal_store(bits[2] + zero, dst + 2);
#endif
"""


@wp.func_native(_NT3)
def stream(a: wp.array[wp.vec3d], i: wp.int32, v: wp.vec3d): ...  # pragma: no cover - native code


_NT3L = """
#if defined(__CUDA_ARCH__)
a.data[i] = v;
#else
long long* dst = reinterpret_cast<long long*>(&a.data[i][0]);
__builtin_nontemporal_store((long long)v[0], dst);
__builtin_nontemporal_store((long long)v[1], dst + 1);
__builtin_nontemporal_store((long long)v[2], dst + 2);
#endif
"""


@wp.func_native(_NT3L)
def stream(a: wp.array[vec3l], i: wp.int32, v: vec3l): ...  # pragma: no cover  # noqa: F811


_NT1 = """
#if defined(__CUDA_ARCH__)
a.data[i] = v;
#else
__builtin_nontemporal_store(v, &a.data[i]);
#endif
"""


@wp.func_native(_NT1)
def stream(a: wp.array[wp.int32], i: wp.int32, v: wp.int32): ...  # pragma: no cover  # noqa: F811


# stream_large: stream() for a destination of at least STREAM_MIN_BYTES, a plain store (into the caches) for a
# smaller one; the size is the whole destination array's, so a pass stores each output one way. For the passes
# that write several outputs at once: the stepped emit kernels stream_large their blended vertices. On the AMD EPYC
# (Zen 4) of session 46 streaming the 512² re-step's emit outputs (faces 22-25 MB, blended vertices 11 MB, face
# levels 4 MB) slowed emit_grid: fastest of 200 replays on one core, eight rounds alternating, 6.3-7.0 ms streamed,
# 5.5-6.1 ms stored plainly; the whole re-step (CPU time, fastest of 50) 9.8-11.2 -> 9.2-10.3 ms. Session 37's Intel
# Xeon found plain stores at that size within noise. A pass writing one output in a sweep gains from streaming there
# even at that size (the γ blend of 512², blend_vertices: 1.0-1.07 ms streamed, 1.24-1.32 ms stored plainly), so it
# keeps stream(); so do count_grid's prefixes (within noise either way). Vertices from 32 MiB (2048²'s: 157 MB)
# stream. The stepped faces and face levels are stored plainly (store()) at every size: until session 47 they
# called stream_large, which clang compiled to plain stores (below), and once it really streamed them emit_grid at
# 2048² (20 steps) took 69-75 ms instead of 62-64 on session 47's EPYC (fastest of 20 replays on one core,
# alternating rounds; faces streamed alone 61-67 against 60-66, within noise; face levels alone 67-69).
STREAM_MIN_BYTES = 32 << 20


# The streaming branch of stream_large: a streaming store clang cannot merge with the plain store of the other
# branch. With __builtin_nontemporal_store alone, the vec3l and int32 stores of both branches (same address, same
# type; the value differing or not) were sunk into one store after the branch, which keeps only the metadata both
# had: a plain store at every size (objdump of session 47's build: no movnti for faces or face levels in emit_grid
# or emit_tin_faces). So each streaming store sits between two empty asm statements that read and write the
# stored location: no instruction, but the branches no longer begin or end alike (SimplifyCFG hoists the stores
# that begin both branches, sinks those that end them, InstCombine merges the last ones) and nothing may move the
# store past them (MergedLoadStoreMotion). With the barrier after each store only, the first of a vec3l's three was
# hoisted out of the branch, a plain store beside two streamed ones in each line: emit_grid at 2048² took 2.1 s
# instead of 65 ms. (The store cannot be a movnti in inline asm: Warp's CPU compiler has no x86 asm parser.) The
# vec3d stores differ in type from the plain branch's (bits, see _NT3) and need no barrier.
_NT_INT = """
auto streamed = [](auto* dst, auto value) {  // one streaming store of a 4- or 8-byte integer (movnti on x86-64)
    __asm__ __volatile__("" : "+m"(*dst));
    __builtin_nontemporal_store(value, dst);
    __asm__ __volatile__("" : "+m"(*dst));
};
"""

_NT3L_LARGE = (
    _NT_INT
    + "long long* dst = reinterpret_cast<long long*>(&a.data[i][0]);\n"
    + "streamed(dst, (long long)v[0]);\nstreamed(dst + 1, (long long)v[1]);\nstreamed(dst + 2, (long long)v[2]);\n"
)
_NT1_LARGE = _NT_INT + "streamed(&a.data[i], v);\n"


def _large_only(streaming: str) -> str:
    """The native body of stream_large from a streaming store's C: a plain store below STREAM_MIN_BYTES on the
    CPU, ``streaming`` from it, a plain store on CUDA."""
    return (
        "#if defined(__CUDA_ARCH__)\na.data[i] = v;\n#else\n"
        f"if ((long long)a.shape[0] * (long long)sizeof(a.data[0]) < {STREAM_MIN_BYTES}LL) {{\n    a.data[i] = v;\n"
        f"}} else {{\n{streaming}}}\n#endif\n"
    )


# The vec3l and int32 overloads serve no kernel since the stepped faces and face levels went to store(); they are
# kept with tests/test_memory.py's checks (exact bits; a streaming store for each part) for a pass that wants them.
# fmt: off
@wp.func_native(_large_only(_NT3.split("#else\n", 1)[1].rsplit("#endif", 1)[0]))
def stream_large(a: wp.array[wp.vec3d], i: wp.int32, v: wp.vec3d): ...  # pragma: no cover - native code
@wp.func_native(_large_only(_NT3L_LARGE))
def stream_large(a: wp.array[vec3l], i: wp.int32, v: vec3l): ...  # pragma: no cover  # noqa: F811
@wp.func_native(_large_only(_NT1_LARGE))
def stream_large(a: wp.array[wp.int32], i: wp.int32, v: wp.int32): ...  # pragma: no cover  # noqa: F811
# fmt: on


@wp.func_native("""
#if !defined(__CUDA_ARCH__)
__atomic_thread_fence(__ATOMIC_SEQ_CST);
#endif
""")
def fence_streams(): ...  # pragma: no cover - native code


@wp.kernel
def drain_streams():
    """Order this CPU thread's streaming stores before its later stores and loads (a full fence)."""
    fence_streams()
