"""A monitor whose queries never wait for frames (a camera period is 33 ms, a control cycle 2 ms).

Cameras deliver a set of frames every 33 ms; a controller asks for distances every 2 ms. :class:`LiveMonitor` takes
each new set with :meth:`~LiveMonitor.submit` and prepares it on a worker thread (self-filtering, the free-space
memory, the depth grid's set-up, and the cells the robot's own control points need), while
:meth:`~LiveMonitor.query` answers at once from the latest fully prepared set. A set submitted while another is being
prepared waits; a newer one replaces it (``dropped`` counts them): the worker always prepares the newest frames.

The worker owns the :class:`DistanceMonitor` (created on it, so that its OpenGL context lives on the thread that
renders); a query reads only the :class:`~depthguard.PreparedSet` the worker published, which the worker
never changes afterwards.

numba runs the worker's and the query's parallel kernels at once only under a thread-safe threading layer (omp or
tbb); under ``workqueue`` they take turns (``serialised``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping

import numpy as np

from depthguard.cameras import PinholeCamera, Rig
from depthguard.depth import depth_image
from depthguard.validation import check_points, check_real
from depthguard.errors import DepthguardError, InputError
from depthguard.results import DistanceResult, Flag

_LOG = logging.getLogger("depthguard")


class LiveMonitor:
    """:class:`DistanceMonitor` with frames prepared in the background: queries never wait for a new set of frames.

    Args:
        rig, **options: as :class:`DistanceMonitor` (``robot=``, ``max_age=``, ``memory=``, ...).

    - :meth:`submit` hands over a set of frames (as :meth:`DistanceMonitor.query` takes them) and returns at once.
    - :meth:`query` answers from the latest prepared set; ``result.timestamps`` say when its frames were captured,
      and ``result.ages`` how old each was at the query's ``now`` (the answer is as old as the oldest, ``result.age``).
      Before the first set is prepared, every point gets distance 0 and ``missing_camera``. When a frame of that set
      is older than ``max_age`` at the query's ``now`` (by default 0.1 s for frames with timestamps), every point gets
      distance 0 and ``stale_camera``: submit frames in time.
    - :meth:`wait` blocks until everything submitted is prepared (tests, replay); :meth:`close` stops the worker.
    - A set the worker cannot prepare (bad input) is skipped and kept in ``errors``: the monitor keeps answering
      from the last good set, and the worker keeps running.

    Use it as a context manager, or call :meth:`close`.
    """

    def __init__(self, rig: Rig, **options):
        self.errors: list[DepthguardError] = []
        self.prepared = 0
        self.dropped = 0
        self._condition = threading.Condition()
        self._inbox = None
        self._busy = False
        self._closed = False
        self._latest = None
        self._robot = options.get("robot")
        self._query_lock = threading.Lock()
        self._ready = threading.Event()
        self._startup_error = None
        self._thread = threading.Thread(target=self._run, args=(rig, options), name="depthguard-live", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._startup_error is not None:
            self._thread.join()
            raise self._startup_error
        self.serialised = _threading_layer() == "workqueue"
        self._kernels = threading.Lock() if self.serialised else None

    # ------------------------------------------------------------------------------------------ the caller's side

    def submit(self, frames: Mapping, *, joints=None, camera_joints=None, now: float | None = None) -> None:
        """Hand over a set of frames (camera name -> :class:`DepthImage` or array), with the robot's joints at their
        capture time (``joints``, or ``camera_joints`` per camera) and ``now``, as :meth:`DistanceMonitor.query`
        takes them. Returns at once; an unprepared set still waiting is replaced (``dropped``)."""
        if self._closed:
            raise InputError("this LiveMonitor is closed", field="submit")
        if not isinstance(frames, Mapping):
            raise InputError(f"frames must map camera names to depth images, got {type(frames).__name__}",
                             field="frames")
        with self._condition:
            if self._inbox is not None:
                self.dropped += 1
            self._inbox = (dict(frames), joints, camera_joints, now)
            self._condition.notify_all()

    def query(self, points_world, *, now: float | None = None) -> DistanceResult:
        """Distances of control points ((n, 3) float64, metres, world frame) from the latest prepared set of
        frames, without waiting for the one being prepared."""
        points = check_points(points_world)
        if now is not None:
            now = check_real(now, "now", unit="seconds", field="now")
        prepared = self._latest
        if prepared is None:
            return DistanceResult.blind(len(points), Flag.MISSING_CAMERA)
        if prepared.untimed_stale and now is None:
            raise InputError("this monitor has max_age set: pass now= (seconds, the frames' clock) to query()",
                             field="now")
        with self._query_lock, _maybe(self._kernels):
            # A frame older than max_age at now (the default 0.1 s for stamped frames) makes the answer blind.
            return prepared.query(points, check=False, now=now)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until every submitted set is prepared (or ``timeout`` seconds pass); True when it is."""
        with self._condition:
            return self._condition.wait_for(lambda: self._inbox is None and not self._busy, timeout)

    def close(self) -> None:
        """Stop the worker (after the set it is preparing) and wait for it."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()
        self._thread.join()

    def __enter__(self) -> "LiveMonitor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def latest_time(self) -> float | None:
        """The latest capture time of the frames queries answer from (seconds), None before the first set."""
        prepared = self._latest
        return None if prepared is None else prepared.time

    # -------------------------------------------------------------------------------------------- the worker

    def _run(self, rig: Rig, options: dict) -> None:
        from depthguard._monitor import DistanceMonitor

        try:
            monitor = DistanceMonitor(rig, **options)
        except BaseException as exc:  # reported to the constructor's caller
            self._startup_error = exc
            self._ready.set()
            return
        self._ready.set()
        while True:
            with self._condition:
                self._condition.wait_for(lambda: self._inbox is not None or self._closed)
                if self._closed:
                    return
                frames, joints, camera_joints, now = self._inbox
                self._inbox = None
                self._busy = True
            try:
                with _maybe(self._kernels):
                    prepared = monitor.prepare_set(frames, joints=joints, camera_joints=camera_joints, now=now)
                    self._classify_near_robot(prepared, joints, camera_joints)
                self._latest = prepared
                self.prepared += 1
            except DepthguardError as exc:
                self.errors.append(exc)
                _LOG.warning("depthguard: LiveMonitor skipped a set of frames: %s", exc)
            finally:
                with self._condition:
                    self._busy = False
                    self._condition.notify_all()

    def _classify_near_robot(self, prepared, joints, camera_joints) -> None:
        """Query the robot's control points once on the worker, so that the cells they need are classified before
        the set is published (the first query's cost is paid here, not by the controller)."""
        if self._robot is None or not prepared.fused:
            return
        q = joints
        if q is None and camera_joints:
            q = next(iter(camera_joints.values()))
        if q is None:
            return
        prepared.query(self._robot.control_point_positions(self._robot.joint_vector(q)), check=False)


class _NoLock:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _maybe(lock):
    return lock if lock is not None else _NoLock()


def _threading_layer() -> str:
    """numba's threading layer, started by a tiny parallel kernel if no parallel kernel has run yet."""
    import numba

    try:
        return numba.threading_layer()
    except ValueError:  # no parallel kernel has run yet
        from depthguard.depthgrid import free_image

        camera = PinholeCamera("layer", 1, 1, 1.0, 1.0, 0.0, 0.0, np.eye(4))
        free_image(depth_image(np.zeros((1, 1), dtype=np.uint16), camera), camera)
        return numba.threading_layer()

