"""``roadtwin drive``: a vehicle drives a route through a composed town on a physics backend
while the sensors of a rig record it on one simulation clock (issue 20).

One concern per module: ``route`` (where the vehicle drives and at what speed: ``auto``, lanes or a
poses file; a sweep's recommendations as a speed profile), ``motion`` (the physics backend drives
it, stretch by stretch, into one :class:`~.motion.Trajectory`), ``rig`` (the rig file: which
sensors sit where, mounted through the ``sensors`` plugin kind), ``world`` (what sensors see: the
renderer plugin, a ray caster, labels), ``traffic`` (other vehicles on the lanes: kinematic boxes
the sensors see), ``contacts`` (wheel-defect contact events), ``bag`` (the
ROS 2 bag, MCAP storage), ``rrd`` (the rerun recording), ``run`` (``run_drive`` ties them
together on the one clock and writes the output folder atomically) and ``many`` (``run_drives``:
one drive a route through the executors)."""
from .route import Route, SpeedProfile, build_route, constant_speed, load_speed_profile, read_recommendations, \
    speed_profile
from .many import read_routes_file, run_drives
from .run import DriveOptions, SensorState, load_stage, prepare_drive, run_drive

__all__ = ["DriveOptions", "Route", "SensorState", "SpeedProfile", "build_route", "constant_speed", "load_stage",
           "load_speed_profile", "prepare_drive", "read_recommendations", "read_routes_file", "run_drive", "run_drives",
           "speed_profile"]
