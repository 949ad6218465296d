"""One home for depthguard's defaults and tolerances.

Kernels never hold literals of their own: every default and tolerance that shapes a result is named here, with its
unit, so that a reviewer can see in one page what the library assumes.
"""

import math

#: Metres per unit of a ``uint16`` depth image (ROS ``16UC1`` images are in millimetres).
DEFAULT_DEPTH_SCALE = 0.001

#: Valid measurement range of a camera when the rig does not state one, metres. Nothing is unseen in depth then:
#: an invalid pixel under ``invalid="occupied"`` is occupied from the optical centre on.
DEFAULT_DEPTH_RANGE = (0.0, math.inf)

#: Radius of the surveillance region around each control point, metres.
DEFAULT_RHO = 0.4

#: Aggregation of the contributors of one control point (SPEC section 6).
DEFAULT_AGGREGATE = "hybrid"
AGGREGATES = ("min", "mean", "hybrid")

#: Policies for pixels without a valid measurement and for space no camera looks at (SPEC section 3).
DEFAULT_INVALID = "occupied"
INVALID_POLICIES = ("occupied", "neighbors", "free")
DEFAULT_UNSEEN = "occupied"
UNSEEN_POLICIES = ("occupied", "free")

#: ``exact`` is SPEC section 4-5; ``paper`` is the 2015 paper's formulas (eqs. 7-11), kept for comparison only.
DEFAULT_METHOD = "exact"
METHODS = ("exact", "paper")

#: ``invalid="neighbors"``: a hole of at most this many 8-connected pixels takes the smallest valid depth around it.
DEFAULT_NEIGHBOR_HOLE_PIXELS = 16

#: Depth noise model sigma(d) = a + b*d + c*d**2 (metres) times k gives the noise margin m(d) (SPEC section 3).
#: The default is the axial noise of a Kinect v1 measured by Nguyen, Izadi and Lovell (3DIMPVT 2012),
#: sigma(d) = 0.0012 + 0.0019*(d - 0.4)**2, expanded into a + b*d + c*d**2, with k = 3.
DEFAULT_NOISE_SIGMA = (0.0012 + 0.0019 * 0.16, -2.0 * 0.4 * 0.0019, 0.0019)
DEFAULT_NOISE_K = 3.0

#: Largest |R^T R - I| entry and |det R - 1| accepted for a rotation read from a file.
ROTATION_TOLERANCE = 1e-6

#: A distance at or below this (metres) means the point lies inside a possibly-occupied set.
INSIDE_TOLERANCE = 1e-12

#: A mean direction shorter than this is reported as the zero vector (obstacles on all sides cancel out).
MIN_DIRECTION_NORM = 1e-9

#: Cube corners at or nearer than this depth (metres, optical frame) make the surveillance window the whole image.
NEAR_PLANE_EPSILON = 1e-6

#: Side of the square pixel blocks whose minimum depth bounds whole blocks at once, pixels.
BLOCK_SIZE = 8
