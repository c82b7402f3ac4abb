"""What a town stage is built from, apart from the merger: seeded, lane-aware defect placement
(``placement``) and lane-marking meshes draped on the merged road (``markings``). The composer
(:mod:`roadtwin_core.apps.compose`) runs them; the USD writer (:mod:`roadtwin_core.usd.town`) reads
their results.
"""
