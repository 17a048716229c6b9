"""Vertex compaction after a face cull, shared by the close-ups (paper 001) and the globe (paper 003).

A cull keeps some faces (count -> scan -> emit over the faces); the vertices no kept face uses are then dropped
by the same pattern over the vertices: :func:`mark_used_vertices` flags the vertices of the kept faces, an
exclusive scan of the flags gives each used vertex its new index, the caller's own emit kernel copies the used
vertices (with whatever per-vertex data it carries) to those indices, and :func:`remap_faces` rewrites the
kept faces' vertex indices. Both kernels are chunked (``thread_offset, count, chunk`` first; launched by
``stepterrain._device.launch_chunked``).
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})  # integer work only: no adjoints, nothing to contract


@wp.kernel
def mark_used_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.vec3i],
    # outputs
    used_out: wp.array[wp.int32],
):
    """One element per kept face: flag its three vertices as used (every writer writes 1)."""
    first = (wp.tid() + thread_offset) * chunk
    t = first
    last = wp.min(first + chunk, count)
    while t < last:
        f = faces[t]
        used_out[f[0]] = 1
        used_out[f[1]] = 1
        used_out[f[2]] = 1
        t += 1


@wp.kernel
def remap_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.vec3i],
    offsets: wp.array[wp.int32],
    # outputs
    faces_out: wp.array[wp.vec3i],
):
    """One element per kept face: its vertex indices after compaction (``faces_out`` may be ``faces``: each
    element reads and writes only its own face)."""
    first = (wp.tid() + thread_offset) * chunk
    t = first
    last = wp.min(first + chunk, count)
    while t < last:
        f = faces[t]
        faces_out[t] = wp.vec3i(offsets[f[0]], offsets[f[1]], offsets[f[2]])
        t += 1
