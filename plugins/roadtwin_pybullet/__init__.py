"""Physics backend ``pybullet``: the same vehicle as a Bullet multibody (prismatic suspension
joints driven by spring-damper forces) over the road as static concave triangle meshes.

The simulator lives in ``sim.py`` (numpy + pybullet only); this module adapts roadtwin's vehicle
types to it. Registered through the ``roadtwin`` entry-point group as
``pybullet = "roadtwin_pybullet"``. CPU only.
"""
from __future__ import annotations

import numpy as np

from roadtwin_core import RoadtwinError, hookimpl
from roadtwin_core.vehicle import RoadMesh, SimParams, Traces, VehicleRun, check_runs, plain_vehicles


class PybulletPhysics:
    name = "pybullet"
    description = ("Bullet multibody vehicle (Featherstone): joint chain for the prescribed path, free "
                   "heave/pitch/roll, 4 prismatic suspensions; tire patch by ray tests on a static concave trimesh.")
    Params = SimParams

    def simulate(self, road_mesh, vehicles: list[VehicleRun], params: SimParams | None = None) -> Traces:
        params = (params or SimParams()).check(f"physics backend {self.name}")
        check_runs(vehicles, f"physics backend {self.name}")
        if params.device != "cpu":
            raise RoadtwinError(f"physics backend {self.name}: runs on the CPU only (got device {params.device!r})")
        road = road_mesh if isinstance(road_mesh, RoadMesh) else RoadMesh(*road_mesh)
        try:
            from . import sim as bullet
        except ImportError as exc:
            raise RoadtwinError(f"physics backend {self.name}: needs pybullet ({exc})") from None
        plain = plain_vehicles(vehicles)
        init = {i: v.initial_state for i, v in enumerate(vehicles) if v.initial_state}
        world = bullet.BulletVehicleSim(road.vertices, road.faces)
        try:
            res = world.run(plain, dt=params.dt_s, imu_rate_hz=params.imu_rate_hz, tire_slices=params.tire_slices,
                            tire_arc_samples=params.tire_arc_samples, tire_arc_deg=params.tire_arc_deg,
                            tire_refine=params.tire_refine,
                            lost_after_s=params.lost_after_s, initial_state=init or None)
        finally:
            world.close()
        meta = {"backend": self.name, "device": "cpu", "wall_s": res["wall_s"], "sim_s": res["sim_s"],
                "setup_s": res["bvh_s"], "dt": params.dt_s, "imu_dt": res["imu_dt"], "mode": res["mode"],
                "triangles": int(len(road.faces)), "mesh_chunks": world.n_chunks}
        return Traces(t=res["t"], acc=res["acc"], gyro=res["gyro"], pose=res["pose"], wheel_z=res["wheel_z"],
                      tire_f=res["tire_f"], susp=res["susp"], valid=res["valid"],
                      off_road=np.asarray(res["dead"], dtype=bool), meta=meta)


@hookimpl
def roadtwin_register_physics_backends(register):
    register(PybulletPhysics())
