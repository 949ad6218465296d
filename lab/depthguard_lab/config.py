"""The lab's defaults: the simulated sensors, people and trajectories (depthguard's own live in depthguard.config).

Every default that shapes a simulation is named here, with its unit.
"""


#: Simulated depth sensor (depthguard_lab.simulation), Kinect-like. Axial noise is Gaussian with sigma(d) from the
#: camera's NoiseModel (a, b, c); values are quantised to the camera's depth_scale. A pixel whose exact depth differs
#: from one of its 4 neighbours by more than SIM_EDGE_THRESHOLD metres (or whose neighbour shows nothing) is a
#: depth-discontinuity pixel and is dropped (set to 0) with probability SIM_EDGE_DROPOUT; a pixel whose surface
#: normal makes more than SIM_GRAZING_ANGLE radians with the ray is dropped with probability SIM_GRAZING_DROPOUT.
SIM_EDGE_THRESHOLD = 0.05
SIM_EDGE_DROPOUT = 0.5
SIM_GRAZING_ANGLE = 1.36  # radians, 78 degrees
SIM_GRAZING_DROPOUT = 0.9

#: Simulated intensity images: Gaussian noise of this standard deviation, in grey levels of the uint8 image.
SIM_INTENSITY_NOISE = 2.0

#: Segments around each person part, sphere and capsule when the simulation renders them (primitive_mesh): the mesh
#: contains the true solid and exceeds it by at most 1.7 % of the radius at 24 (2.5 mm on a 0.15 m torso).
SIM_PRIMITIVE_SEGMENTS = 24

#: Frame rate of the simulated cameras and of the episode's time steps, Hz.
SIM_RATE = 30.0

#: zlib level of the PNGs write_episode writes (0-9): 1 writes a noisy 640x480 depth image about 3.5 times as fast
#: as the default 6, and only about 5 % bigger.
SIM_PNG_COMPRESSION = 1

#: Albedo (reflectance in [0, 1]) of the robot in simulated intensity images, and the defaults of people's clothes
#: and skin (hands, head) and of static objects.
SIM_ROBOT_ALBEDO = 0.8
SIM_CLOTHES_ALBEDO = 0.35
SIM_SKIN_ALBEDO = 0.6
SIM_OBJECT_ALBEDO = 0.5

#: Robot Cartesian trajectories (the vertical hexagon): damped least-squares IK on the end-effector's positional
#: Jacobian with damping SIM_IK_DAMPING (metres), a null-space pull of gain SIM_IK_POSTURE_GAIN towards the
#: trajectory's posture, iterated per frame until the end-effector is within SIM_IK_TOLERANCE metres of its target
#: (at most SIM_IK_ITERATIONS iterations). A frame left farther than SIM_IK_MAX_ERROR from its target is an error
#: (the path is out of reach).
SIM_IK_DAMPING = 0.02
SIM_IK_POSTURE_GAIN = 0.1
SIM_IK_TOLERANCE = 1e-6
SIM_IK_ITERATIONS = 200
SIM_IK_MAX_ERROR = 0.005

#: People: default walking speed (m/s), leg swing amplitude (radians of hip flexion) and stride length per metre of
#: body height (one stride = two steps), and how long (s) heading changes and gait starts/stops are blended over.
SIM_WALK_SPEED = 1.3
SIM_LEG_SWING = 0.35
SIM_STRIDE_PER_HEIGHT = 0.8
SIM_PERSON_BLEND = 0.3

#: People: default time (s) an arm takes to move into or out of a reaching pose.
SIM_REACH_RAMP = 0.5

