"""Physics backend ``warp``: N vehicles per launch over the road collision mesh, CPU or CUDA.

The kernels live in ``kernels.py`` (numpy + warp + roadtwin's path resampling); this module
adapts roadtwin's vehicle types to them. Registered
through the ``roadtwin`` entry-point group as ``warp_physics = "roadtwin_warp_physics"``.
"""
from __future__ import annotations

import numpy as np

from roadtwin_core import RoadtwinError, hookimpl
from roadtwin_core.vehicle import RoadMesh, SimParams, Traces, VehicleRun, check_runs, plain_vehicles


class WarpPhysics:
    name = "warp"
    description = ("Tire-level vehicle dynamics in warp kernels: 6-DOF body (heave/roll/pitch free, path "
                   "prescribed), 4 suspensions, ray-sampled radial-spring tires, IMU; CPU or CUDA, batched.")
    Params = SimParams

    def simulate(self, road_mesh, vehicles: list[VehicleRun], params: SimParams | None = None) -> Traces:
        params = (params or SimParams()).check(f"physics backend {self.name}")
        check_runs(vehicles, f"physics backend {self.name}")
        road = road_mesh if isinstance(road_mesh, RoadMesh) else RoadMesh(*road_mesh)
        try:
            from . import kernels
        except ImportError as exc:  # warp missing
            raise RoadtwinError(f"physics backend {self.name}: needs warp-lang ({exc})") from None
        plain = plain_vehicles(vehicles)
        for p in {id(v["params"]): v["params"] for v in plain}.values():
            limit = kernels.max_stable_dt(p)
            if params.dt_s > limit:
                raise RoadtwinError(f"physics backend {self.name}: dt {params.dt_s} s is too large for vehicle "
                                    f"{p['name']!r} (stiffest wheel mode needs dt <= {limit:.2e} s)")
        try:
            sim = kernels.VehicleSim(road.vertices, road.faces, device=params.device)
        except (RuntimeError, ValueError) as exc:
            raise RoadtwinError(f"physics backend {self.name}: device {params.device!r} is not available "
                                f"({str(exc).splitlines()[0]})") from None
        init = {i: v.initial_state for i, v in enumerate(vehicles) if v.initial_state}
        res = sim.run(plain, dt=params.dt_s, imu_rate_hz=params.imu_rate_hz, tire_slices=params.tire_slices,
                      tire_arc_samples=params.tire_arc_samples, tire_arc_deg=params.tire_arc_deg,
                      tire_refine=params.tire_refine,
                      lost_after_s=params.lost_after_s, initial_state=init or None)
        meta = {"backend": self.name, "device": str(sim.device), "wall_s": res["wall_s"], "sim_s": res["sim_s"],
                "setup_s": res["bvh_s"], "dt": params.dt_s, "imu_dt": res["imu_dt"], "mode": res["mode"],
                "triangles": int(len(road.faces))}
        return Traces(t=res["t"], acc=res["acc"], gyro=res["gyro"], pose=res["pose"], wheel_z=res["wheel_z"],
                      tire_f=res["tire_f"], susp=res["susp"], valid=res["valid"],
                      off_road=np.asarray(res["dead"], dtype=bool), meta=meta)


@hookimpl
def roadtwin_register_physics_backends(register):
    register(WarpPhysics())
