"""How a :class:`~depthguard.DistanceMonitor` answers: its settings, one validated dataclass."""

from __future__ import annotations

from dataclasses import dataclass

from depthguard import config
from depthguard.validation import check_choice, check_options, check_real, check_whole, short_repr
from depthguard.errors import InputError


@dataclass(frozen=True)
class MonitorSettings:
    """Every setting of a :class:`~depthguard.DistanceMonitor` that is a value (the objects it works with, the rig, a
    robot, known solids, principals and maps, are its own arguments). Each field is checked when the settings are made:
    a wrong type or a value out of range raises :class:`~depthguard.errors.InputError` naming it.

    Attributes:
        rho: radius of each control point's surveillance region, metres, in [``config.RHO_MIN``,
            ``config.RHO_MAX``]; obstacles farther away are ignored.
        aggregate: ``"min"``, ``"mean"`` or ``"hybrid"`` (design §6).
        invalid: policy for pixels without a valid measurement: ``"occupied"`` (fail-safe), ``"neighbors"`` (a
            concession, flagged ``hole_filled``) or ``"free"`` (design §3).
        unseen: policy for space no camera observes: ``"occupied"`` (fail-safe) or ``"free"``.
        method: ``"exact"`` (design) or ``"paper"`` (the 2015 paper's unsafe formulas, for comparison only).
        max_age: seconds, in (0, ``config.MAX_AGE_LIMIT``]; a frame older than this at query time (``now``) makes
            its camera blind and the result flagged, and so does a frame without a timestamp. ``"auto"`` (default):
            ``config.DEFAULT_MAX_AGE`` (0.1 s, three frame periods at 30 Hz) for every frame that carries a
            timestamp; frames without one cannot age. None: frames do not go stale by age.
        hole_pixels: largest hole filled by ``invalid="neighbors"``, pixels, in [0, ``config.MAX_HOLE_PIXELS``].
        self_filter: the geometry rendered for self-filtering: ``"hulls"`` (default), ``"capsules"`` or
            ``"meshes"`` (:mod:`depthguard.self_filter`).
        self_filter_tolerance: metres, in [0, ``config.SELF_FILTER_TOLERANCE_MAX``], by which a measurement may lie
            in front of the rendered robot and still be the robot (on top of the noise margin; a concession,
            flagged ``robot_shell``).
        fusion_margin: metres (finite, >= 0) a secondary camera must have seen beyond a cell to clear it (the rig's
            calibration error, on top of the noise margin).
        fusion_pixels: pixels, in [0, ``config.MAX_FUSION_PIXELS``], by which a cell's footprint grows in a
            secondary camera.
        memory: remember free space over time (design §8a): space no camera sees now counts free while no person
            moving at ``v_max`` could have reached it since it was last seen free. It needs frame timestamps and the
            rig's ``workspace`` (the box remembered, in voxels of ``memory_voxel`` metres); without a workspace, or
            with a rig of one camera, there is no memory. Fused answers only; an answer that rests on it is flagged
            ``remembered``. A body part moving faster than v_max is outside the guarantee.
        v_max: metres/second, finite, > 0: the fastest a person may move (default 2.0, ISO 13855's hand speed).
        memory_voxel: metres, > 0: the memory's voxel side.
        robot_zone: metres, in [0, ``config.ROBOT_ZONE_MAX``]; fused answers with a robot take space within this much
            of the robot's padded capsules for the robot, in every direction (a concession, flagged ``robot_zone``):
            an object wholly inside it is not seen. 0 (default) turns it off.
        detection_capability: d, metres, in (0, 70 mm] (ISO 13855), or None (default): with a value, each set of
            frames also finds where in the possibly occupied space a ball of diameter d fits
            (:class:`depthguard.freespace.DetectableSpace`, in voxels of ``detectable_voxel`` over the rig's
            ``workspace``, which it needs), for speed and separation monitoring only
            (:meth:`PreparedSet.detectable_distances`): the space counted free there is what some usable camera sees
            entirely free now, what the memory remembers, the robot's capsules grown by ``robot_zone``, and the
            known solids' inside. The monitor refuses d plus the band its concessions can hide next to a surface
            above 70 mm (``DistanceMonitor._hidden_band``).
        detectable_voxel: metres, in (0, d / 2]: the voxels' side (default ``config.DETECTABLE_VOXEL``, 1 cm).
    """

    rho: float = config.DEFAULT_RHO
    aggregate: str = config.DEFAULT_AGGREGATE
    invalid: str = config.DEFAULT_INVALID
    unseen: str = config.DEFAULT_UNSEEN
    method: str = config.DEFAULT_METHOD
    max_age: float | str | None = "auto"
    hole_pixels: int = config.DEFAULT_NEIGHBOR_HOLE_PIXELS
    self_filter: str = "hulls"
    self_filter_tolerance: float = config.SELF_FILTER_TOLERANCE
    fusion_margin: float = config.DEFAULT_FUSION_MARGIN
    fusion_pixels: int = config.DEFAULT_FUSION_PIXELS
    memory: bool = config.DEFAULT_MEMORY
    v_max: float = config.FREESPACE_V_MAX
    memory_voxel: float = config.FREESPACE_VOXEL
    robot_zone: float = config.DEFAULT_ROBOT_ZONE
    detection_capability: float | None = None
    detectable_voxel: float = config.DETECTABLE_VOXEL

    def __post_init__(self):
        values = {"rho": check_options(self.rho, self.aggregate, self.unseen, self.method),
                  "invalid": check_choice(self.invalid, "invalid", config.INVALID_POLICIES)}
        if not (self.max_age is None or (isinstance(self.max_age, str) and self.max_age == "auto")):
            values["max_age"] = check_real(self.max_age, "max_age", minimum=0.0, above_minimum=True,
                                           maximum=config.MAX_AGE_LIMIT, unit="seconds", field="max_age")
        values["hole_pixels"] = check_whole(self.hole_pixels, "hole_pixels", config.MAX_HOLE_PIXELS)
        values["self_filter"] = check_choice(self.self_filter, "self_filter", config.SELF_FILTER_GEOMETRIES)
        values["self_filter_tolerance"] = check_real(
            self.self_filter_tolerance, "self_filter_tolerance", minimum=0.0, maximum=config.SELF_FILTER_TOLERANCE_MAX,
            unit="metres", field="self_filter_tolerance")
        values["fusion_margin"] = check_real(self.fusion_margin, "fusion_margin", minimum=0.0, unit="metres",
                                             field="fusion_margin")
        values["fusion_pixels"] = check_whole(self.fusion_pixels, "fusion_pixels", config.MAX_FUSION_PIXELS)
        values["robot_zone"] = check_real(self.robot_zone, "robot_zone", minimum=0.0, maximum=config.ROBOT_ZONE_MAX,
                                          unit="metres", field="robot_zone")
        if not isinstance(self.memory, bool):
            raise InputError(f"memory must be True or False, got {short_repr(self.memory)}", field="memory")
        values["v_max"] = check_real(self.v_max, "v_max", minimum=0.0, above_minimum=True,
                                     maximum=config.COORDINATE_LIMIT, unit="metres/second", field="v_max")
        values["memory_voxel"] = check_real(self.memory_voxel, "memory_voxel", minimum=0.0, above_minimum=True,
                                            maximum=config.COORDINATE_LIMIT, unit="metres", field="memory_voxel")
        if self.detection_capability is not None:
            capability = check_real(self.detection_capability, "detection_capability", minimum=0.0,
                                    above_minimum=True, maximum=config.COORDINATE_LIMIT, unit="metres",
                                    field="detection_capability")
            if capability > config.SSM_INTRUSION_LIMIT:
                raise InputError(f"detection_capability {capability:g} m is coarser than ISO 13855's 70 mm: no "
                                 "intrusion distance C is defined for it", field="detection_capability")
            values["detection_capability"] = capability
        # Checked whether or not it is used: every number a user gives is (docs/bad-input.md).
        largest = config.COORDINATE_LIMIT if self.detection_capability is None else \
            values["detection_capability"] / 2
        values["detectable_voxel"] = check_real(self.detectable_voxel, "detectable_voxel", minimum=0.0,
                                                above_minimum=True, maximum=largest, unit="metres",
                                                field="detectable_voxel")
        for name, value in values.items():
            object.__setattr__(self, name, value)

    @property
    def max_age_seconds(self) -> float | None:
        """Seconds after which a frame with a timestamp is stale (None: never)."""
        if isinstance(self.max_age, str):
            return config.DEFAULT_MAX_AGE
        return self.max_age

    @property
    def untimed_stale(self) -> bool:
        """Whether a frame without a timestamp is stale: only under a max_age given explicitly."""
        return not (self.max_age is None or isinstance(self.max_age, str))
