"""``roadtwin plan``: orchestration (:mod:`.stage`), file writers (:mod:`.writers`), figures
(:mod:`.plots`), the USD curves layer (:mod:`.usd_layer`), bypass-or-cross decisions from a
vibration sweep (:mod:`.decisions`) and the console report (:mod:`.report`)."""
from .decisions import Decision, decide, defects_on_route, load_recommendations, sweep_vehicle_name, write_decisions
from .stage import PlanRun, plan_stage

__all__ = ["Decision", "decide", "defects_on_route", "load_recommendations", "sweep_vehicle_name",
           "write_decisions", "PlanRun", "plan_stage"]
