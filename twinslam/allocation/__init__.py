"""One edge's keyframe budget split between devices: what a keyframe is worth to a device
(``budget_value.py``) and the allocators that split V_total (``allocators.py``)."""
