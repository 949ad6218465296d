"""The kernel layer: every numba kernel of depthguard, in one package below the packages that use them.

Each module here serves one package above it and is named for it; its names are public inside the layer, and a
package above imports the module, never a name that starts with an underscore:

============================  ===========================================================================
``frustum``                   a pixel frustum's exact nearest point (design §4), the surveillance region
                              (§5), the aggregation of contributors (§6), the noise margin: shared by the
                              single camera and the depth grid
``depthspace``                the single-camera distance (``depthguard.depthspace``)
``depth``                     a frame's preparation: start depths, self-filter, hole fill, block minima
                              (``depthguard.depth``)
``depthgrid``                 the depth grid's fusion (``depthguard.depthgrid``, design §8)
``freespace``                 the free-space memory (``depthguard.freespace``, design §8a)
``detectable``                the detectable space for SSM (``depthguard.freespace.DetectableSpace``, §9)
``capsules``                  the capsule fit of a robot's links (``depthguard.robots``)
``collision``,                the image-based collision test, its reference update and its planner
``collision_update``,         (``depthguard.collision``, design §10)
``collision_plan``
``jit``                       how every kernel is compiled and cached (:func:`jit.kernel`)
============================  ===========================================================================

Conventions, the same in every module:

- Units: metres, seconds, radians; pixels for image coordinates, whose centres are whole numbers (pixel (u, v)
  spans [u - 1/2, u + 1/2] x [v - 1/2, v + 1/2]).
- Frames: a camera's optical frame (x right, y down, z forward) for everything in depth space; the world frame
  (REP 103) for voxels and capsules. A transform is passed as ``R`` (3, 3) float64 and ``t`` (3,) float64, mapping
  its source frame into its target: x_target = R x_source + t.
- Images: (h, w) arrays indexed [v, u], C order; raw depth as the camera's integers or floats (``raw``) with
  ``scale`` metres per unit, what is derived from it as float32 metres (each module says what inf and 0 mean in
  its arrays).
- Voxels: (nx, ny, nz) arrays indexed [i, j, k] along world x, y, z from the box's near corner ``lo`` (3,) float64,
  voxels ``voxel`` metres a side.
- Records: a kernel that needs many arrays of one thing takes them as one namedtuple, documented where it is
  defined (the depth grid's ``GridState``, ``PrincipalView``, ``QueryOptions``, ``FusedOutput``); numba compiles a
  namedtuple of arrays and scalars as separate arguments. The depth grid is passed as its ``GridState`` ``grid``
  to every kernel that reads it, except the small helpers called per pixel (``depthgrid.cell_index``,
  ``known_free``, ``surface_cell_end``, ``nearest_by_run``, ``distance_by_runs``), which take its numbers and arrays
  apart: a record holding arrays, handed to an inlined function, costs a reference count per array per call (per
  pixel it made later fused queries 1.7 times as slow). The kernels that take the record and are called per pixel,
  walk or run (``classify_run``, ``remembered_cells``, ``occupied_in``, ``nearest_confirmed``, ``fused_rows``,
  ``fused_region``) are compiled without reference counting (``jit.kernel(refcounts=False)``): they allocate
  nothing and return no array, and with counting each call counted every array of the record up and down again.
- One aggregation (design §6): both walks over contributing pixels, the single camera's (``depthspace``) and the
  depth grid's (``depthgrid``), add each pixel's :func:`frustum.contribution` and finish with
  :func:`frustum.finish_sum` (``mean``, ``hybrid``) or :func:`frustum.finish_min_at_pixel` (``min``).
- Arguments: every argument of every kernel is documented with its shape, dtype and unit, in the kernel's docstring
  or in its module's glossary (``Arguments used throughout:``); ``tests/test_kernel_docs.py`` checks it.
- Outputs: the kernels of the online path (frames to distances) write into arrays their caller allocated (``out``,
  ``*_out``, the records' arrays) and allocate nothing per pixel or per point; the collision test's and the capsule
  fit's allocate small scratch arrays per call or per thread.
- Inputs are trusted: each kernel's caller, in the package above, checks shapes, dtypes and ranges first. The tests
  hold the kernels against slow NumPy twins (``tests/naive.py``) and run their bodies as plain Python
  (``.py_func``).
"""
